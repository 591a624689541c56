"""models.lut (``gonio lut``'s library; docs/lut.md): definitions and their parametrizations, small
tables against the quadratures and closed forms within their standard errors, the pilot's rays
for a target standard error, the checks themselves, a published table compared, the coat tables
and OpenPBR's formulas scored, and the writers (C header compiled, 16-bit PNG read back)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from goniometer import optics
from models.lut import (LutError, check_table, compare_published, compute_table, definition_from_dict,
                        load_definition, read_c_array, reference_values, score_darkening, write_table)
from models.lut.check import coat_closed_form, compare, z_cells
from models.lut.compute import RAYS_STEP, SAFETY, plan_table, rays_for_target
from models.lut.definition import ior_from_f0
from models.lut.quantities import conductor_extinction, incident_elevations
from models.lut.writers import c_float, header_text, png16

from goniometer.testing import Z_TOL

CONFIGS = Path(__file__).resolve().parents[2] / "configs" / "lut"

#: a 3 x 3 table of Cycles' layout (mu rows, r columns, alpha = r^2, node-aligned, clamped)
SMALL = {"name": "small_E", "quantity": "albedo", "masking": "height-correlated", "rays": 40_000,
         "interface": {"fresnel": "white"},
         "axes": [{"parameter": "mu", "nodes": 3, "clamp": [1e-4, 1.0]},
                  {"parameter": "roughness", "nodes": 3, "clamp": [1e-4, 1.0], "map": "alpha=r^2"}]}


def definition(**changes):
    d = json.loads(json.dumps(SMALL))
    d.update(changes)
    return definition_from_dict(d)


@pytest.fixture(scope="module")
def small():
    return compute_table(definition(), threads=1)


# --------------------------------------------------------------------------- definitions

def test_the_cycles_definition_is_cycles_grid():
    d = load_definition(CONFIGS / "cycles-ggx-E.toml")
    assert d.shape == (32, 32) and d.quantity == "albedo" and d.masking == "height-correlated"
    assert d.name == "table_ggx_E" and d.published.array == "table_ggx_E" and d.published.decimals == 6
    mu, alpha = d.axis_values()
    i = np.arange(32)
    np.testing.assert_allclose(mu, np.maximum(i / 31, 1e-4), rtol=1e-15)
    np.testing.assert_allclose(alpha, np.maximum(i / 31, 1e-4) ** 2, rtol=1e-15)   # alpha = r^2, r clamped
    assert d.stderr < 2e-4


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.toml")), ids=lambda p: p.stem)
def test_every_shipped_definition_loads_and_plans(path):
    d = load_definition(path)
    plan = plan_table(d)
    assert len(plan.rows) * (d.shape[d.incident_axis] if d.incident_axis is not None else 1) == d.cells


def test_placements_clamps_and_the_index_from_f0():
    d = definition(axes=[{"parameter": "mu", "nodes": 4, "placement": "texel"},
                         {"parameter": "roughness", "nodes": 3, "map": "alpha=r", "range": [0.2, 0.6]}])
    mu, alpha = d.axis_values()
    np.testing.assert_allclose(mu, (np.arange(4) + 0.5) / 4)
    np.testing.assert_allclose(alpha, [0.2, 0.4, 0.6])
    z = np.array([1e-4, 0.3, 0.7, 0.99])
    eta = ior_from_f0(z ** 4)
    np.testing.assert_allclose(eta, (1 + z ** 2) / (1 - z ** 2), rtol=1e-14)
    # the index whose normal-incidence reflectance is z^4 (Cycles' ior_from_F0)
    np.testing.assert_allclose(optics.np_fresnel_dielectric(np.ones(4), eta), z ** 4, rtol=1e-9, atol=1e-18)
    glass = load_definition(CONFIGS / "cycles-ggx-glass-E.toml")
    np.testing.assert_allclose(glass.axis_values()[0], ior_from_f0(np.clip(np.arange(16) / 15, 1e-4, 0.99) ** 4))


def test_theta_axis_and_incident_elevations():
    d = definition(axes=[{"parameter": "theta", "nodes": 3, "range": [0.0, 80.0]},
                         {"parameter": "roughness", "nodes": 1, "range": [0.5, 0.5], "map": "alpha=r^2"}])
    theta, w = incident_elevations(d)
    np.testing.assert_allclose(theta, [0.0, 40.0, 80.0])
    assert w is None
    avg = definition(quantity="albedo-average", axes=[SMALL["axes"][1]])
    theta, w = incident_elevations(avg)
    mu = np.cos(np.radians(theta))
    assert len(mu) == avg.average_nodes and np.all((mu > 0) & (mu < 1))
    np.testing.assert_allclose(np.sum(w * np.ones_like(mu)), 1.0, rtol=1e-13)    # 2 Int mu dmu = 1
    np.testing.assert_allclose(np.sum(w * mu), 2.0 / 3.0, rtol=1e-13)


BAD = [
    ({"rays": None}, "rays, stderr: give exactly one"),
    ({"stderr": 1e-3}, "rays, stderr: give exactly one"),
    ({"rays": 0}, "rays: 0 is outside [1,"),
    ({"colour": 1}, "colour: unknown key"),
    ({"name": "ggx-E"}, "name: 'ggx-E' must be a C identifier"),
    ({"quantity": "albedos"}, "quantity: 'albedos' is not one of"),
    ({"masking": "smith"}, "masking: 'smith' is not one of"),
    ({"axes": [{"parameter": "mu", "nodes": 0}]}, "axes[0].nodes: 0 is outside [1, 4096]"),
    ({"axes": [{"parameter": "mu", "nodes": 4}]}, "axes[0]: a node gives mu 0, outside (0, 1]"),
    ({"axes": [{"parameter": "theta", "nodes": 4}]}, "axes[0]: a node gives theta 90, outside [0, 90)"),
    ({"axes": [{"parameter": "mu", "nodes": 2, "clamp": [0.5, 1.5]}]}, "axes[0].clamp: [0.5, 1.5] must satisfy"),
    ({"axes": [SMALL["axes"][0], {"parameter": "roughness", "nodes": 2}]}, "axes[1].map: a roughness axis says how"),
    ({"axes": [SMALL["axes"][0], dict(SMALL["axes"][1], map="alpha=r^3")]}, "axes[1].map: 'alpha=r^3' is not one of"),
    ({"axes": [SMALL["axes"][1]]}, "axes: an albedo table needs an incident axis"),
    ({"axes": SMALL["axes"] + [dict(SMALL["axes"][0], parameter="theta", clamp=[0, 0.5])]},
     "axes[2].parameter: one incident axis only"),
    ({"axes": SMALL["axes"] + [dict(SMALL["axes"][0])]}, "axes[2].parameter: mu is already set by axes[0]"),
    ({"interface": {"fresnel": "white", "ior": 1.5}}, "interface.ior: a white interface (F = 1) takes no ior"),
    ({"interface": {"fresnel": "white", "roughness": 0.1}}, "interface.roughness: set by axes[1] too"),
    ({"interface": {"fresnel": "conductor", "ior": 0.2}}, "interface.extinction: None is outside (0, inf)"),
    ({"interface": {"fresnel": "dielectric"}}, "interface.ior: required"),
    ({"interface": {"fresnel": "dielectric", "ior": 1.5, "side": "below"}}, "interface.side: 'below' is not one of"),
    ({"part": "transmitted"}, "part: a white interface transmits nothing"),
    ({"coat": {"ior": 1.5}}, "coat: an albedo table has no [coat]"),
    ({"quantity": "albedo-average"}, "axes[0].parameter: an albedo-average table has no incident axis"),
    ({"quantity": "coat-roughness", "interface": None, "axes": [],
      "coat": {"ior": 1.5, "roughness": 0.1}, "base": {"kind": "lambertian", "albedo": 0.5}},
     "base.kind: a coat-roughness table needs a conductor base"),
    ({"quantity": "coat-darkening", "interface": None, "axes": [SMALL["axes"][0]],
      "coat": {"ior": 1.5, "roughness": 0.1}, "base": {"kind": "lambertian", "albedo": 0.5, "roughness": 0.1}},
     "base.roughness: a Lambertian base takes no roughness"),
    ({"quantity": "coat-darkening", "interface": None, "axes": [SMALL["axes"][0]],
      "coat": {"ior": 1.5, "roughness": 0.1}, "base": {"kind": "conductor", "albedo": 1.5, "roughness": 0.1}},
     "base.albedo: 1.5 is outside [0, 1]"),
    ({"score": {"tolerance": 0.1}}, "score: only a coat-darkening table is scored"),
    ({"darkening": "albedo"}, "darkening: only a coat-darkening table takes it"),
    ({"quantity": "coat-darkening", "interface": None, "axes": [SMALL["axes"][0]], "resolution": [45, 1],
      "coat": {"ior": 1.5, "roughness": 0.1}, "base": {"kind": "lambertian", "albedo": 0.5}},
     "resolution: only the production estimators record slices"),
]


@pytest.mark.parametrize("change, needle", BAD, ids=[n for _, n in BAD])
def test_a_bad_definition_is_one_error_naming_the_field(change, needle):
    d = json.loads(json.dumps(SMALL))
    for k, v in change.items():
        if v is None:
            d.pop(k, None)
        else:
            d[k] = v
    with pytest.raises(LutError) as e:
        definition_from_dict(d)
    assert needle in str(e.value), str(e.value)
    assert "\n" not in str(e.value)


def test_a_conductor_of_a_given_f0():
    for f0, eta in ((0.2, 1.0), (0.9, 1.0), (0.5, 0.3), (0.6, 2.5)):
        k = conductor_extinction(f0, eta)
        assert k > 0
        np.testing.assert_allclose(optics.fresnel_conductor(1.0, eta, k), f0, rtol=1e-12)
    with pytest.raises(LutError, match=r"base.albedo: 0.1 is outside \(0.183673, 1\]"):
        conductor_extinction(0.1, 2.5)


# --------------------------------------------------------------------------- computed tables

def test_a_small_cycles_table_agrees_with_the_quadrature(small):
    d = small.definition
    assert small.values.shape == small.stderr.shape == small.rays.shape == (3, 3)
    assert np.all(small.rays == 40_000)
    checks = {c.name: c for c in check_table(small)}
    assert set(checks) == {"quadrature", "fresnel"}
    assert all(c.passed for c in checks.values()), [c.line() for c in checks.values()]
    assert checks["quadrature"].cells == 9 and checks["fresnel"].cells == 3
    # the smooth column (r clamped to 1e-4, alpha 1e-8) keeps everything; the others lose to masking
    np.testing.assert_allclose(small.values[:, 0], 1.0, atol=1e-9)
    assert np.all(small.stderr[:, 1:] > 0) and np.all(small.values[1:, 2] < 0.6)
    # two of Cycles' published nodes (table_ggx_E, 6 decimals): (mu 1, r 1) and (mu 1e-4, r 1)
    for (i, j), cycles in (((2, 2), 0.306853), ((0, 2), 0.999079)):
        assert abs(small.values[i, j] - cycles) < Z_TOL * np.hypot(small.stderr[i, j], 5e-7), (i, j)
    assert d.axis_values()[0][0] == 1e-4


def test_the_check_catches_a_cell_off_by_its_errors(small):
    ref, err, _ = reference_values(small.definition)
    bad = small.values.copy()
    bad[1, 1] += 8.0 * small.stderr[1, 1]
    c = compare("quadrature", "test", bad, small.stderr, ref, err)
    assert not c.passed and c.worst == [1, 1] and c.failures[0]["cell"] == [1, 1]
    assert z_cells(9) > Z_TOL > z_cells(1) - 1e-12


def test_separable_masking_is_another_table():
    sep = compute_table(definition(masking="separable", rays=20_000), threads=1)
    assert all(c.passed for c in check_table(sep))
    hc = reference_values(definition())[0]
    # separable Smith masking loses more than the height-correlated form (r = 1, mu = 0.5: 0.41 vs 0.45)
    assert sep.values[1, 2] + Z_TOL * sep.stderr[1, 2] < hc[1, 2] - 0.02


@pytest.mark.parametrize("interface, part", [
    ({"fresnel": "dielectric", "ior": 1.5, "side": "outside"}, "both"),
    ({"fresnel": "dielectric", "ior": 1.5, "side": "inside"}, "both"),
    ({"fresnel": "dielectric", "ior": 1.5, "side": "inside"}, "reflected"),
    ({"fresnel": "conductor", "ior": 0.3, "extinction": 3.0}, "both"),
])
def test_interfaces_agree_with_the_quadrature_and_fresnel(interface, part):
    r = compute_table(definition(interface=interface, part=part, rays=20_000), threads=1)
    checks = {c.name: c for c in check_table(r)}
    assert {"quadrature", "fresnel"} <= set(checks)
    assert all(c.passed for c in checks.values()), [c.line() for c in checks.values()]
    if interface["fresnel"] == "conductor":   # the smooth column is the conductor's Fresnel reflectance
        mu = r.definition.axis_values()[0]
        np.testing.assert_allclose(r.values[:, 0], optics.np_fresnel_conductor(mu, 0.3, 3.0), atol=1e-6)


def test_multiple_scattering_conserves_energy():
    r = compute_table(definition(interface={"fresnel": "dielectric", "ior": 1.5, "side": "inside"},
                                 multiple_scattering=True, rays=5_000), threads=1)
    checks = {c.name: c for c in check_table(r)}
    assert checks["energy"].passed and "quadrature" not in checks
    np.testing.assert_allclose(r.values, 1.0, atol=1e-12)


def test_average_albedo_and_a_target_standard_error():
    d = definition(quantity="albedo-average", rays=None, stderr=2e-4, axes=[SMALL["axes"][1]])
    r = compute_table(d, threads=1)
    assert r.values.shape == (3,) and r.pilot_rays > 0
    assert all(c.passed for c in check_table(r))
    # rays follow each row's spread: the smooth row needs a step, the rough one more
    assert r.rays[0] == RAYS_STEP and r.rays[2] > r.rays[1] > r.rays[0]
    assert np.all(r.stderr <= 1.5 * 2e-4) and r.stderr[2] > 0.5 * 2e-4
    assert rays_for_target(2e-3, 1000, 1e-3) == int(np.ceil(SAFETY * 4000 / RAYS_STEP) * RAYS_STEP)


@pytest.mark.slow
def test_cycles_ggx_e_full_size_below_2e4_everywhere_and_on_the_quadrature():
    # the issue's "done when": Cycles' 32 x 32 ggx_E at standard errors below 2e-4 per cell, agreeing
    # with the quadrature everywhere (about 6 min on 2 cores; make lut runs the shipped 1.5e-4)
    d = load_definition(CONFIGS / "cycles-ggx-E.toml").with_rays(stderr=1.8e-4)
    r = compute_table(d)
    assert r.values.shape == (32, 32) and float(np.max(r.stderr)) < 2e-4
    checks = {c.name: c for c in check_table(r)}
    assert checks["quadrature"].passed and checks["quadrature"].cells == 1024, checks["quadrature"].line()


def test_same_seed_same_bits_whatever_the_threads():
    a = compute_table(definition(rays=5_000), threads=1)
    b = compute_table(definition(rays=5_000), threads=2)
    assert a.values.tobytes() == b.values.tobytes() and a.stderr.tobytes() == b.stderr.tobytes()
    c = compute_table(definition(rays=5_000, seed=2), threads=1)
    assert c.values.tobytes() != a.values.tobytes()


# --------------------------------------------------------------------------- coat tables

COAT = {"name": "dark", "quantity": "coat-darkening", "rays": 30_000,
        "coat": {"roughness": 0.0}, "base": {"kind": "lambertian", "albedo": 0.6},
        "axes": [{"parameter": "coat_ior", "nodes": 2, "range": [1.0, 1.5]},
                 {"parameter": "mu", "nodes": 2, "placement": "texel"}]}


@pytest.mark.parametrize("darkening", ["albedo", "production"])
def test_coat_darkening_over_a_lambertian_has_its_closed_form(darkening):
    r = compute_table(definition_from_dict(dict(COAT, darkening=darkening)), threads=1)
    checks = {c.name: c for c in check_table(r)}
    assert checks["closed-form"].passed and checks["closed-form"].cells == 4, checks["closed-form"].line()
    ref, sel, _ = coat_closed_form(r.definition)
    np.testing.assert_allclose(ref[0], 1.0)              # index-matched: absent
    assert np.all(ref[1] < 0.95) and sel.all()           # a coat of 1.5 darkens
    if darkening == "production":    # the estimator's P leaves out the coat's entry: grazing light darkens more
        assert ref[1, 0] < ref[1, 1]
        return
    s = score_darkening(r)
    f = s["formulas"]
    assert set(f) == {"openpbr-1.1", "openpbr-corrected-269", "openpbr-node-graph", "standard-surface"}
    # over a rough (Lambertian) base the specification's formula and the corrected one agree, and are
    # the exact geometric series: no cell fails them
    assert f["openpbr-1.1"]["rmse"] == pytest.approx(f["openpbr-corrected-269"]["rmse"], rel=1e-12)
    assert f["openpbr-1.1"]["failing_cells"] == 0 and f["openpbr-1.1"]["rmse"] < 5 * r.stderr.max()


def test_coat_roughness_of_an_index_matched_coat_is_the_bases():
    d = definition_from_dict({"name": "rough", "quantity": "coat-roughness", "rays": 30_000,
                              "coat": {"ior": 1.0, "roughness": 0.1},
                              "base": {"kind": "conductor", "albedo": 0.9},
                              "axes": [{"parameter": "base_roughness", "nodes": 2, "range": [0.3, 0.5],
                                        "map": "alpha=r^2"}]})
    r = compute_table(d, threads=1)
    checks = {c.name: c for c in check_table(r)}
    assert checks["closed-form"].passed, checks["closed-form"].line()
    np.testing.assert_allclose(r.values, [0.09, 0.25], atol=Z_TOL * r.stderr.max())
    # scattering multiply, the base's lobe gains a broad background the estimator reads as rougher
    assert coat_closed_form(definition_from_dict(dict(json.loads(json.dumps(d.to_dict())), multiple_scattering=True))) \
        is None


# --------------------------------------------------------------------------- a published table

def test_a_published_table_off_in_one_cell(small, tmp_path):
    published = np.round(small.values, 6)
    published[2, 1] += 0.01
    src = tmp_path / "tables.c"
    body = ", ".join(f"{x:.6f}f" for x in published.ravel())
    src.write_text(f"/* {{ not this }} */\nstatic const float other[2] = {{1.0f, 2.0f}};\n"
                   f"static const float small_E[9] = {{\n  {body},\n}};\n")
    got = read_c_array(src, "small_E")
    np.testing.assert_array_equal(got, np.array([float(f"{x:.6f}") for x in published.ravel()]))
    out = compare_published(small, got, 6, reference_values(small.definition))
    assert [c["cell"] for c in out["beyond_ours"]] == [[2, 1]]
    assert [c["cell"] for c in out["beyond_quadrature"]][0] == [2, 1]
    with pytest.raises(LutError, match="no array nothing"):
        read_c_array(src, "nothing")
    with pytest.raises(LutError, match="holds 2 numbers; the table has 9 cells"):
        compare_published(small, read_c_array(src, "other"), 6)


# --------------------------------------------------------------------------- writers

def test_c_float_literals():
    assert c_float(1.0) == "1.0f" and c_float(0.0) == "0.0f"
    assert c_float(1e-10).endswith("e-10f") and c_float(0.306853) == "0.306852996f"
    assert float(np.float32(float(c_float(0.306853)[:-1]))) == float(np.float32(0.306853))


def test_the_header_compiles_and_prints_a_value(small, tmp_path):
    cc = shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler (cc) on this machine: the header's compile test needs one")
    (tmp_path / "small_E.h").write_text(header_text(small, "test"))
    (tmp_path / "main.c").write_text('#include <stdio.h>\n#include "small_E.h"\n'
                                     'int main(void) { printf("%.9g %.9g %d\\n", small_E[5], small_E_stderr[5], '
                                     '(int)(sizeof(small_E) / sizeof(small_E[0]))); return 0; }\n')
    subprocess.run([cc, "-std=c99", "-Wall", "-Werror", "-Wno-unused-const-variable", "-o", str(tmp_path / "main"),
                    str(tmp_path / "main.c")], check=True, cwd=tmp_path)
    value, stderr, n = subprocess.run([str(tmp_path / "main")], check=True, capture_output=True,
                                      text=True).stdout.split()
    # the printed float is the table's value in single precision
    assert np.float32(float(value)) == np.float32(small.values.ravel()[5])
    assert np.float32(float(stderr)) == np.float32(small.stderr.ravel()[5]) and int(n) == 9


def test_files_json_and_png(small, tmp_path):
    Image = pytest.importorskip("PIL.Image")
    doc = small.to_json()
    paths = write_table(tmp_path, small, dict(doc, checks=[]))
    assert set(paths) == {"values", "stderr", "json", "header", "png"}
    np.testing.assert_array_equal(np.load(paths["values"]), small.values)
    np.testing.assert_array_equal(np.load(paths["stderr"]), small.stderr)
    j = json.loads(paths["json"].read_text())
    assert j["shape"] == [3, 3] and np.array(j["values"]).shape == (3, 3) and j["rays"] == [[40_000] * 3] * 3
    assert [a["parameter"] for a in j["axes"]] == ["mu", "roughness"] and j["definition"]["name"] == "small_E"
    np.testing.assert_allclose(j["axes"][1]["values"], small.definition.axis_values()[1])
    img = np.array(Image.open(paths["png"]))
    assert img.dtype == np.uint16 and img.shape == (3, 3)
    np.testing.assert_array_equal(img, np.round(small.values * 65535).astype(np.uint16))
    # a 3-D table lays its slices side by side
    cube = np.linspace(0, 1, 24).reshape(2, 3, 4)
    from models.lut.writers import image_layout
    np.testing.assert_array_equal(image_layout(cube), np.concatenate([cube[0], cube[1]], axis=1))
    assert png16(np.zeros((1, 1)))[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_white_base_under_a_coat_is_not_darkened_and_the_corrected_numerator_is():
    # a smooth coat over a smooth-ish white conductor, both scattering multiply: nothing is
    # absorbed, so the darkening is 1 (closed form); OpenPBR 1.1's (1 - K)/(1 - E_b K) is 1 at
    # E_b = 1 for every K, the corrected (1 - K_r)/(1 - E_b K) is not where K = lerp(K_s, K_r, r_b) < K_r
    d = definition_from_dict({"name": "white", "quantity": "coat-darkening", "rays": 20_000,
                              "multiple_scattering": True, "coat": {"ior": 1.5, "roughness": 0.0},
                              "base": {"kind": "conductor", "albedo": 1.0, "roughness": 0.04},
                              "axes": [{"parameter": "mu", "nodes": 2, "placement": "texel"}]})
    r = compute_table(d, threads=1)
    checks = {c.name: c for c in check_table(r)}
    assert checks["closed-form"].passed and checks["closed-form"].cells == 2, checks["closed-form"].line()
    f = score_darkening(r)["formulas"]
    assert f["openpbr-1.1"]["failing_cells"] == 0
    assert f["openpbr-corrected-269"]["failing_cells"] == 2 and f["openpbr-corrected-269"]["max_abs_error"] > 0.05
