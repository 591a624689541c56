"""Honest first runs: every kernel variant a run needs is compiled before tracing (timed as compile,
never booked as tracing), the user is told while it compiles, progress moves within an incident
direction, and a resumed run's rate leaves out what the checkpoints held."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numba
import pytest

from goniometer.cli.common import LineProgress, ResumeAware, compile_kernels
from goniometer.run.loop import run_incidents
from goniometer.run.settings import SimulationSettings
from goniometer.stack import Interface, Lambertian, Medium, Stack, load_toml
from goniometer.run.tasks import run_variant, trace_incident, warm_up, warm_up_runs

EXAMPLES = Path(__file__).resolve().parents[2] / "configs" / "examples"


def _overloads() -> dict[str, int]:
    """Compiled signatures of every numba function of the simulator, by qualified name."""
    out = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith("goniometer") or module is None:
            continue
        for attr, value in vars(module).items():
            if isinstance(value, numba.core.dispatcher.Dispatcher):
                out[f"{name}.{attr}"] = len(value.overloads)
    return out


@pytest.mark.parametrize("case", ["plastic", "metal-hc-half", "metal-integrated", "metal-polarized"])
def test_warm_up_compiles_everything_the_run_then_calls(case):
    """After warm_up(stack, settings), tracing and assembling the run compiles nothing more. (With
    the old warm-up of one default stack, the metal's kernel variant compiled inside its first
    task and was booked as tracing; a polarized run's warm-up once ran the scalar variant.)"""
    metal, _ = load_toml(EXAMPLES / "metal.toml")
    stack, settings = {
        "plastic": (Stack("p", (Interface(0.2, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Lambertian((0.2, 0.5, 0.8)))),
                    SimulationSettings(incident_deg=(30.0,), rays=3000, resolution=(9, 18), threads=1)),
        "metal-hc-half": (metal, SimulationSettings(incident_deg=(0.0, 30.0), rays=3000, resolution=(9, 18),
                                                    parametrization="half", masking="height-correlated",
                                                    max_order=3, threads=1)),
        "metal-integrated": (metal, SimulationSettings(incident_deg=(30.0,), rays=3000, resolution=(9, 18),
                                                       first_order="integrated", threads=1)),
        "metal-polarized": (metal, SimulationSettings(incident_deg=(30.0,), rays=3000, resolution=(9, 18), threads=1,
                                                      polarized=True)),
    }[case]
    warm_up(stack, settings)
    before = _overloads()
    run_incidents(stack, settings)
    after = _overloads()
    grew = {k: (before.get(k, 0), n) for k, n in after.items() if n != before.get(k, 0)}
    assert not grew, f"compiled while tracing: {grew}"


def test_a_database_warms_each_variant_once(monkeypatch):
    import goniometer.run.tasks as tasks
    metal, _ = load_toml(EXAMPLES / "metal.toml")
    plastic = Stack("p", (Interface(0.2, (1.5,) * 3), Lambertian((0.5,) * 3)))
    s = SimulationSettings(incident_deg=(30.0,), rays=100, resolution=(9, 18))
    calls = []
    monkeypatch.setattr(tasks, "warm_up", lambda stack, settings: calls.append(stack.name))
    warm_up_runs([(metal, s), (metal, s.with_overrides(rays=200)), (plastic, s)])
    assert calls == [metal.name, "p"]
    assert run_variant(metal, s) != run_variant(metal, s.with_overrides(masking="height-correlated"))


def _slow(seconds: float, then=None):
    def warm_up() -> float:
        if then is not None:
            then()
        time.sleep(seconds)
        return seconds
    return warm_up


class _CachedDispatcher:
    """What numba's compile event carries for a function of ours with an on-disk cache."""

    class _cache:
        cache_path = "/numba/cache"

    py_func = staticmethod(_slow)        # a function of ours (numba's own implementations are cached with their caller)


def _numba_compiles(dispatcher) -> None:
    """Announce a compile exactly as numba's Dispatcher.compile does (its ``numba:compile`` event)."""
    import numba.core.event as ev
    with ev.trigger_event("numba:compile", data={"dispatcher": dispatcher}):
        pass


def test_compile_notice_is_shown_only_while_compiling():
    err = io.StringIO()
    assert compile_kernels(lambda: 0.01, file=err) == 0.01
    assert err.getvalue() == ""  # a quick cache load says nothing
    err = io.StringIO()
    assert compile_kernels(_slow(1.4, lambda: _numba_compiles(_CachedDispatcher())), variants=3, file=err) == 1.4
    text = err.getvalue()
    assert text.startswith("compiling kernels (first run only, about 75 s)")
    assert "compiled kernels in 1." in text and "(cached for later runs)" in text

    def broken() -> float:
        raise RuntimeError("numba says no")
    with pytest.raises(RuntimeError, match="numba says no"):
        compile_kernels(broken, file=io.StringIO())


def test_a_slow_cache_load_is_not_called_compiling():
    """A warm-up that takes over a second but compiles nothing (numba loads every function from its
    cache, here: kernels this process already has) says so; it was announced as 'compiling kernels
    (first run only, about 45 s)' with its seconds booked as compiling."""
    stack = Stack("p", (Interface(0.2, (1.5,) * 3), Lambertian((0.5,) * 3)))
    s = SimulationSettings(incident_deg=(30.0,), rays=100, resolution=(9, 18), threads=1)
    warm_up(stack, s)
    err = io.StringIO()
    compile_kernels(_slow(1.3, lambda: warm_up(stack, s)), file=err)
    assert err.getvalue().splitlines()[0] == "loading compiled kernels ..."
    assert err.getvalue().splitlines()[-1].startswith("loaded compiled kernels in 1.")
    assert "compiling" not in err.getvalue()


def test_on_a_terminal_one_line_counts_up_and_changes_its_words_when_compiling_starts():
    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    def load_then_compile() -> None:
        time.sleep(1.6)                    # loading past the first second ...
        _numba_compiles(_CachedDispatcher())   # ... then numba compiles

    err = Terminal()
    compile_kernels(_slow(0.6, load_then_compile), file=err)
    shown = [part for part in err.getvalue().split("\r\033[K") if part]
    assert shown[0].startswith("loading compiled kernels: ")
    assert any(part.startswith("compiling kernels (first run only, about 45 s): ") for part in shown)
    assert shown[-1].startswith("compiled kernels in ") and shown[-1].endswith("(cached for later runs)\n")


def test_a_real_compile_is_announced_and_an_uncached_one_not_as_first_run_only():
    import numba
    fresh = numba.njit(lambda x: x + 1)       # no on-disk cache: compiled in every process
    err = io.StringIO()
    compile_kernels(_slow(1.2, lambda: fresh(1)), file=err)
    lines = err.getvalue().splitlines()
    assert lines[0] == "compiling kernels (not cached on disk: every run compiles them) ..."
    assert lines[-1].startswith("compiled kernels in ") and "cached" not in lines[-1]


def test_progress_moves_within_an_incident_direction():
    stack = Stack("p", (Interface(0.2, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Lambertian((0.2, 0.5, 0.8))))
    s = SimulationSettings(incident_deg=(30.0,), rays=40_000, resolution=(9, 18), chunk_rays=4096,
                           chunks_per_task=8, threads=2)
    calls: list[int] = []
    trace_incident(stack, s, 0, progress=calls.append)
    assert sum(calls) == 40_000 and len(calls) == 5  # 10 chunks, one per thread a call
    assert calls[-1] == 40_000 - 9 * 4096 + 4096  # the last call holds the short last chunk


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_line_progress_prints_on_time_too_and_leaves_resumed_work_out_of_the_rate():
    clock, out = Clock(), io.StringIO()
    bar = LineProgress(1000, "m", file=out, clock=clock, every_s=30.0)
    from tqdm import tqdm
    bar.skip(500)  # half was done before this run (checkpoints)
    assert out.getvalue().count("\n") == 1 and "50%" in out.getvalue()
    clock.t = 10.0
    bar.update(10)
    assert out.getvalue().count("\n") == 1  # no new tenth, 10 s after the last line
    clock.t = 40.0
    bar.update(10)  # no new tenth either, but 30 s have passed: a line
    last = out.getvalue().splitlines()[-1]
    assert out.getvalue().count("\n") == 2 and "52%" in last
    assert f" {tqdm.format_sizeof(20 / 40)} ray/s" in last  # 20 rays traced in 40 s, not 520
    progress = ResumeAware(bar)
    progress.resumed(100)
    progress(150)  # 100 loaded, 50 traced
    assert bar.n == 670 and bar.skipped == 600


@pytest.mark.slow
def test_a_cold_cache_run_records_the_rate_of_a_warm_run(tmp_path):
    """The rays/s a first run records (empty numba cache, compile included in the wall time) is
    within 30 % of a warm run's: compile is timed apart."""
    env = dict(os.environ, GONIOMETER_CACHE=str(tmp_path / "cache"))
    env.pop("NUMBA_CACHE_DIR", None)
    rates = []
    for k in range(2):
        out = tmp_path / f"m{k}.h5"
        subprocess.run([sys.executable, "-m", "goniometer.cli", "simulate", str(EXAMPLES / "metal.toml"), "--out",
                        str(out), "--rays", "2000000", "--incident", "0,30,60", "--threads", "2"],
                       env=env, check=True, capture_output=True)
        info = subprocess.run([sys.executable, "-m", "goniometer.cli", "info", str(out), "--json"], env=env,
                              check=True, capture_output=True, text=True)
        d = json.loads(info.stdout)["performance"]
        rates.append(d["rays_per_s"])
        if k == 0:
            assert d["compile_s"] > 5.0  # it did compile, and said so
    assert abs(rates[0] / rates[1] - 1.0) < 0.3, rates
