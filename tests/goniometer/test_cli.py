"""The gonio command line: simulate, info, bad input (one line, exit 2, no file), Ctrl-C."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from goniometer.cli import main
from tests.conftest import PLASTIC_TOML, child_sigint_default

EXAMPLES = Path(__file__).resolve().parents[2] / "configs" / "examples"
GOOD = PLASTIC_TOML + """[simulation]
incident_deg = [0, 45]
rays = 2000
resolution = [9, 18]
"""


def test_simulate_then_info(tmp_path, capsys):
    out = tmp_path / "m.h5"
    code = main(["simulate", str(EXAMPLES / "metal.toml"), "--out", str(out), "--rays", "3000",
                 "--incident", "0,30", "--resolution", "9x18", "--seed", "4", "--threads", "1",
                 "--parametrization", "half", "--masking", "height-correlated", "--max-order", "3"])
    assert code == 0 and out.exists()
    capsys.readouterr()
    assert main(["info", str(out), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["material"]["name"] == "metal/M4-a0_0.2-a1_0.2" and d["material"]["category"] == "metal"
    s = d["settings"]
    assert s["incident_deg"] == [0.0, 30.0] and s["rays"] == 3000 and s["resolution"] == [9, 18]
    assert s["seed"] == 4 and s["parametrization"] == "half" and s["masking"] == "height-correlated"
    assert s["max_order"] == 3 and d["performance"]["threads"] == 1 and d["performance"]["rays_per_s"] > 0
    assert len(d["energy"]) == 2 and set(d["energy"][0]) >= {"reflected", "transmitted", "absorbed", "masking_loss"}
    assert main(["info", str(out)]) == 0
    assert "metal/M4" in capsys.readouterr().out


def test_file_table_is_used_and_overridden(tmp_path, capsys):
    cfg = tmp_path / "p.toml"
    cfg.write_text(GOOD)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "a.h5")]) == 0
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "b.h5"), "--incident", "10:90"]) == 0
    capsys.readouterr()
    main(["info", str(tmp_path / "a.h5"), "--json"])
    a = json.loads(capsys.readouterr().out)
    main(["info", str(tmp_path / "b.h5"), "--json"])
    b = json.loads(capsys.readouterr().out)
    assert a["settings"]["incident_deg"] == [0.0, 45.0] and a["settings"]["rays"] == 2000
    assert b["settings"]["incident_deg"] == [10.0] and b["settings"]["incident_phi_deg"] == [90.0]


BAD_CASES = [
    ("invalid.toml", "name = \n", [], "invalid TOML"),
    ("layer.toml", GOOD.replace('type = "lambertian"', 'type = "velvet"'), [], "layers[1].type"),
    ("key.toml", GOOD.replace("roughness = 0.2", "roughness = 0.2\nshine = 1"), [], "layers[0].shine"),
    ("rough.toml", GOOD.replace("roughness = 0.2", "roughness = 2"), [], "layers[0].roughness"),
    ("tau.toml", GOOD.replace('[[layers]]\ntype = "lambertian"', '[[layers]]\ntype = "medium"\noptical_depth = -1\n[[layers]]\ntype = "lambertian"'), [], "layers[1].optical_depth"),
    ("rho.toml", GOOD.replace("albedo = 0.5", "albedo = 1.5"), [], "layers[1].albedo"),
    ("order.toml", GOOD.replace('type = "lambertian"\nalbedo = 0.5', 'type = "lambertian"\nalbedo = 0.5\n[[layers]]\ntype = "interface"\nroughness = 0.1\nior = 1.5'), [], "layers[1].type"),
    ("rays.toml", GOOD, ["--rays", "0"], "rays"),
    ("inc.toml", GOOD, ["--incident", "0,90"], "incident_deg: 90"),
    ("inc2.toml", GOOD, ["--incident", "abc"], "--incident"),
    ("res.toml", GOOD, ["--resolution", "90by360"], "--resolution"),
    ("sim.toml", GOOD.replace("rays = 2000", "rays = -5"), [], "simulation.rays"),
]


@pytest.mark.parametrize("fname, text, extra, expected", BAD_CASES)
def test_bad_input_is_one_line_exit_2_and_no_file(tmp_path, capsys, fname, text, extra, expected):
    cfg = tmp_path / fname
    cfg.write_text(text)
    out = tmp_path / "out.h5"
    code = main(["simulate", str(cfg), "--out", str(out)] + extra)
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.startswith("gonio: error: ") and expected in err and "\n" not in err
    assert not out.exists()
    if "layers" in expected or "TOML" in expected:
        assert str(cfg) in err


def test_existing_output_is_not_touched_on_error(tmp_path, capsys):
    cfg = tmp_path / "p.toml"
    cfg.write_text(GOOD)
    out = tmp_path / "keep.h5"
    out.write_bytes(b"keep me")
    assert main(["simulate", str(cfg), "--out", str(out), "--rays", "0"]) == 2
    assert out.read_bytes() == b"keep me"


def test_unwritable_output(tmp_path, capsys):
    cfg = tmp_path / "p.toml"
    cfg.write_text(GOOD)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "missing-dir" / "x.h5")]) == 2
    assert "does not exist" in capsys.readouterr().err
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if os.access(ro, os.W_OK):
            pytest.skip("running as a user who can write anywhere (root)")
        assert main(["simulate", str(cfg), "--out", str(ro / "x.h5")]) == 2
        assert "not writable" in capsys.readouterr().err
    finally:
        ro.chmod(0o700)


def test_info_on_a_bad_file(tmp_path, capsys):
    bad = tmp_path / "x.h5"
    bad.write_text("nope")
    assert main(["info", str(bad)]) == 2
    assert capsys.readouterr().err.startswith("gonio: error: ")


@pytest.fixture
def sigint_default():
    """SIGINT handled by Python's default handler during the test (restored after)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.parametrize("when", ["tracing", "compiling"])
def test_ctrl_c_leaves_no_partial_file(tmp_path, tmp_path_factory, when):
    """Ctrl-C while tracing, or early in a cold numba compilation (where Python would drop the
    KeyboardInterrupt raised inside a finalizer, or numba would turn it into a RuntimeError):
    exit status 130, nothing written."""
    cfg = tmp_path / "p.toml"
    cfg.write_text(GOOD)
    out = tmp_path / "big.h5"
    env = dict(os.environ)
    if when == "compiling":
        env["GONIOMETER_CACHE"] = str(tmp_path_factory.mktemp("cold-cache"))
        env.pop("NUMBA_CACHE_DIR", None)
    proc = subprocess.Popen([sys.executable, "-m", "goniometer.cli", "simulate", str(cfg), "--out", str(out),
                             "--rays", "200000000", "--threads", "1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=env, preexec_fn=child_sigint_default)
    try:
        # the banner is printed before the kernel is compiled or loaded
        deadline = time.time() + 120
        banner = b""
        while b"simulating" not in banner and time.time() < deadline:
            banner += proc.stderr.read1(1024)
        time.sleep(1.0 if when == "tracing" else 3.0)  # a cold compilation takes 10 s or more
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert b"interrupted" in err
    if when == "compiling":
        assert b"stopping once the kernel is compiled" in err
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["p.toml"]


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # the drop itself
def test_sigint_latch_keeps_an_interrupt_python_dropped(sigint_default):
    """A KeyboardInterrupt raised while a finalizer runs is dropped by Python ("Exception ignored
    in ..."); the latch raises it again at the next check."""
    from goniometer.cli.common import sigint_latch as _sigint_latch

    class Finalized:
        def __del__(self):
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):  # the handler runs at one of these bytecodes, inside __del__
                pass

    with _sigint_latch() as interrupts:
        Finalized()  # dropped at once: __del__ runs here and swallows the KeyboardInterrupt
        assert interrupts.hit
        with pytest.raises(KeyboardInterrupt):
            interrupts.check()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored


def test_sigint_latch_leaves_an_ignored_sigint_ignored():
    from goniometer.cli.common import sigint_latch as _sigint_latch

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with _sigint_latch() as interrupts:
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGINT)
            interrupts.check()
            assert not interrupts.hit
    finally:
        signal.signal(signal.SIGINT, previous)


def test_sigint_latch_defers_inside_compilation(sigint_default):
    from goniometer.cli.common import sigint_latch as _sigint_latch

    with _sigint_latch() as interrupts:
        with pytest.raises(KeyboardInterrupt):
            with interrupts.deferred():
                os.kill(os.getpid(), signal.SIGINT)
                for _ in range(1000):
                    pass
                reached = True  # not interrupted inside the block
        assert reached
        with pytest.raises(KeyboardInterrupt):  # outside a deferred block it raises at once
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):
                pass


# ----------------------------------------------------------------------------- models and evaluate

@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    d = tmp_path_factory.mktemp("eval")
    for name in ("plastic", "slab"):
        assert main(["simulate", str(EXAMPLES / f"{name}.toml"), "--out", str(d / f"{name}.h5"), "--rays", "20000",
                     "--incident", "0,60", "--resolution", "18x36"]) == 0
    return d


def test_models_lists_the_fixed_names(capsys):
    assert main(["models", "--json"]) == 0
    names = json.loads(capsys.readouterr().out)
    assert {"ww09", "elek10", "ww-bati19"} <= set(names)
    assert main(["models"]) == 0


def test_evaluate_json_contract(simulated, capsys, tmp_path):
    out = tmp_path / "model-slices.h5"
    capsys.readouterr()
    assert main(["evaluate", str(simulated / "plastic.h5"), "--json", "--save-slices", str(out)]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["material"] == "plastic/P1-a0_0.05" and d["category"] == "plastic" and d["side"] == "brdf"
    assert {"ww09", "elek10", "ww-bati19"} <= set(d["models"])
    for name, e in d["models"].items():
        for part in ("internal", "total"):
            E = e[part]
            assert set(E) >= {"rmse", "rmse_mean", "rmse_luminance", "noise_floor", "noise_floor_mean"}
            assert len(E["rmse"]) == 3 and len(E["noise_floor"]) == 3
            assert all(x >= 0 for x in E["rmse"])
    for name, reason in d["skipped"].items():
        assert isinstance(reason, str) and reason
    from models.evaluation import read_slices
    sl = read_slices(out, "ww-bati19", "brdf")
    assert sl["value"].shape == (2, 3, 18, 36)
    np.testing.assert_allclose(sl["value"], sl["top"] + sl["internal"])
    _model_slices_open_in_xarray(out, sl)


def _model_slices_open_in_xarray(path, sl):
    """Every group of a model-slices file has named dimensions (h5netcdf strict mode raises on
    unlabeled axes); goniometer.open_dataset reads a model's group with masked cells as NaN."""
    import importlib.util
    if not (importlib.util.find_spec("xarray") and importlib.util.find_spec("h5netcdf")):
        pytest.skip("xarray and h5netcdf are not installed")
    import h5netcdf
    import goniometer

    def walk(g):
        for v in g.variables.values():
            assert not any(d.startswith("phony_dim") for d in v.dimensions), (g.name, v.name)
        for child in g.groups.values():
            walk(child)
    with h5netcdf.File(path, "r") as f:
        walk(f)
    ds = goniometer.open_dataset(path, side="brdf", model="ww-bati19")
    assert ds["value"].dims == ("incident", "channel", "theta", "phi") and "incident_phi" in ds.coords
    m = np.broadcast_to(sl["mask"][:, None], sl["value"].shape)
    np.testing.assert_array_equal(ds["value"].values[m], sl["value"][m])
    assert np.isnan(ds["top"].values[~m]).all()


def test_evaluate_table_and_bad_input(simulated, capsys, tmp_path):
    assert main(["evaluate", str(simulated / "plastic.h5"), "--model", "ww09"]) == 0
    assert "ww09" in capsys.readouterr().out
    out = tmp_path / "never.h5"
    cases = [
        (["evaluate", str(simulated / "plastic.h5"), "--model", "nope", "--save-slices", str(out)], "unknown model"),
        (["evaluate", str(simulated / "slab.h5"), "--model", "ww09", "--save-slices", str(out)], "ww09"),
        (["evaluate", str(tmp_path / "missing.h5")], "no such file"),
    ]
    bad = tmp_path / "truncated.h5"
    bad.write_bytes((simulated / "plastic.h5").read_bytes()[:5000])
    cases.append((["evaluate", str(bad)], "truncated.h5"))
    nobtdf = tmp_path / "nobtdf.h5"
    nobtdf.write_bytes((simulated / "slab.h5").read_bytes())
    import h5py
    with h5py.File(nobtdf, "a") as f:
        del f["btdf"]
    cases.append((["evaluate", str(nobtdf)], "no BTDF"))
    for argv, expected in cases:
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.startswith("gonio: error: ") and expected in err and "\n" not in err, err
        assert not out.exists()


def test_fit_and_fitted_models_in_evaluate(simulated, capsys):
    assert main(["fit", str(simulated / "plastic.h5"), "--model", "ggx1", "--json", "--starts", "2"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["model"] == "ggx1-fit" and set(d["params"]) >= {"kd", "ks", "alpha"} and isinstance(d["converged"], bool)
    assert all(np.isfinite(x) for v in d["params"].values() for x in np.atleast_1d(v))
    assert main(["evaluate", str(simulated / "plastic.h5"), "--model", "ggx1-fit", "--model", "ww09", "--json"]) == 0
    e = json.loads(capsys.readouterr().out)
    assert set(e["models"]) == {"ggx1-fit", "ww09"} and "ggx1-fit" in e["fits"]
    assert e["models"]["ggx1-fit"]["internal"] == e["models"]["ggx1-fit"]["total"]
    # a slab is judged on its BTDF: a fitted BRDF model is refused there, one line, exit 2
    assert main(["evaluate", str(simulated / "slab.h5"), "--model", "ggx1-fit"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gonio: error: ") and "BRDF models" in err and "\n" not in err
    assert main(["fit", str(simulated / "missing.h5"), "--model", "hp15"]) == 2


def test_incident_azimuth_out_of_range_and_fit_without_brdf(simulated, tmp_path, capsys):
    cfg = tmp_path / "p.toml"
    cfg.write_text(GOOD)
    out = tmp_path / "x.h5"
    assert main(["simulate", str(cfg), "--out", str(out), "--incident", "30:360"]) == 2
    err = capsys.readouterr().err.strip()
    assert "incident_phi_deg: 360 is outside [0, 360)" in err and "\n" not in err and not out.exists()
    # a file without BRDF slices cannot be fitted by a BRDF model
    import h5py
    nobrdf = tmp_path / "btdf-only.h5"
    nobrdf.write_bytes((simulated / "slab.h5").read_bytes())
    with h5py.File(nobrdf, "a") as f:
        del f["brdf"]
    assert main(["fit", str(nobrdf), "--model", "ggx1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("gonio: error: ") and "brdf" in err.lower() and "\n" not in err


# ----------------------------------------------------------------------------- plot

def test_plot_writes_the_figures_of_one_file(simulated, tmp_path, capsys):
    out = tmp_path / "fig"
    assert main(["plot", str(simulated / "slab.h5"), "--out", str(out), "--model", "all", "--incident", "60",
                 "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    names = sorted(Path(p).name for p in r["figures"])
    assert names == ["energy.png", "orders_theta60_phi0.png", "plane_theta60_phi0.png",
                     "top_theta60_phi0_belcour-btdf.png", "top_theta60_phi0_reference.png"]  # named by angle
    for p in r["figures"]:
        assert Path(p).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert r["evaluation"]["side"] == "btdf" and "belcour-btdf" in r["evaluation"]["models"]
    # without models: the reference alone, every incident direction
    assert main(["plot", str(simulated / "plastic.h5"), "--out", str(out / "p")]) == 0
    text = capsys.readouterr().out
    assert "wrote 7 figures" in text  # energy + (plane, orders, top) x 2 incident directions


def test_plot_bad_input(simulated, tmp_path, capsys):
    slab = str(simulated / "slab.h5")
    assert main(["plot", slab, "--out", str(tmp_path / "a"), "--incident", "33"]) == 2
    assert "no incident direction at theta = 33" in capsys.readouterr().err
    assert main(["plot", slab, "--out", str(tmp_path / "b"), "--model", "ww09"]) == 2
    assert "ww09" in capsys.readouterr().err
    assert main(["plot", str(tmp_path / "missing.h5"), "--out", str(tmp_path / "c")]) == 2
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_plot_draws_a_spectral_file_in_linear_srgb(tmp_path, capsys, monkeypatch):
    """A spectral file's bins are drawn as their linear sRGB (result.rgb(), docs/spectral.md §4), and
    every figure title says so: 6 bins used to crash (broadcast error), 3 bins were read as R, G, B."""
    from goniometer.files import slices as store
    from models.report import figures
    f = tmp_path / "sp.h5"
    assert main(["simulate", str(EXAMPLES / "plastic.toml"), "--out", str(f), "--rays", "2000", "--incident", "60",
                 "--resolution", "9x18", "--spectral", "--wavelength-bins", "3"]) == 0
    titles, bars = [], []
    save = figures.save_figure

    def spy(fig, path):
        titles.append(fig._suptitle.get_text() if fig._suptitle is not None else fig.axes[0].get_title())
        if Path(path).name == "energy.png":
            bars.extend(p.get_height() for p in fig.axes[0].patches)
        return save(fig, path)
    monkeypatch.setattr(figures, "save_figure", spy)
    capsys.readouterr()
    assert main(["plot", str(f), "--out", str(tmp_path / "fig"), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert len(r["figures"]) == 4 and "linear sRGB" in r["reference"] and "3 wavelength bins" in r["reference"]
    assert len(titles) == 4 and all("linear sRGB of 3 wavelength bins" in t for t in titles), titles
    rgb = store.read(f).rgb()
    np.testing.assert_allclose(bars, figures.order_energy(rgb.brdf)[0], rtol=1e-12)   # one incident, K orders
