"""The checks of a table (``docs/lut.md`` section 7): every cell against what the project
already knows exactly, within the cell's standard error.

* **quadrature**: single-scattering albedo tables against the deterministic quadratures of
  :mod:`models.tables` -- :func:`models.tables.microfacet_albedo.direct` (Kulla-Conty's albedo
  tables: F = 1, or a dielectric's reflection + transmission) and, for a conductor or a
  dielectric's reflected part, :func:`models.tables.fgd_direct_many` (Belcour's FGD).
* **fresnel**: cells whose GGX alpha is at most :data:`ALPHA_SMOOTH` against the smooth
  interface's closed form (Fresnel's reflectance; 1 for reflection + transmission).
* **energy**: a multiple-scattering white conductor, or a dielectric's reflection +
  transmission, keeps everything: 1.
* **closed form** of coat tables: an index-matched coat is absent (darkening 1; the base's own
  roughness); a smooth coat over a Lambertian has a geometric series (``docs/lut.md`` 7).

A check passes when the chi-square of the cells' deviations (each over its combined standard
error: the cell's, the reference's error bound and the floor :data:`EXACT` in quadrature) is
below its limit at the false-alarm probability :data:`P_FALSE_ALARM`, and no single cell
deviates by more than :func:`z_cells` combined standard errors (the same probability for the
whole table). The floor stands for rounding: a cell without spread (every path the same weight,
e.g. 1 on a nearly smooth interface) must match to a few times it.

Also here: a published table compared with ours (:func:`compare_published`, reading its C
array with :func:`read_c_array`), and the formulas of OpenPBR and Standard Surface scored on
coat tables (:func:`score_darkening`, :func:`score_roughness`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from goniometer.optics import np_fresnel_conductor, np_fresnel_dielectric
from models.lut.compute import LutResult
from models.lut.definition import Definition, LutError
from models.lut.quantities import cell_parameters
from models.tables import fgd_direct_many
from models.tables.microfacet_albedo import direct, fresnel_average

#: false-alarm probability of every check (as the test suite's)
P_FALSE_ALARM = 1e-6
#: standard errors of a two-sided false-alarm probability P_FALSE_ALARM for one cell
Z_TOL = float(stats.norm.isf(P_FALSE_ALARM / 2))
#: the albedo quadrature's product rule (cap heights x azimuths) and a coarser one for its error
QUAD = (768, 1024)
QUAD_COARSE = (384, 512)
#: Gauss-Legendre nodes of the reference E_avg (the table's own rule has ``average_nodes``)
AVERAGE_REFERENCE_NODES = 96
#: stated error of Belcour's FGD quadrature where Fresnel is smooth, and at the kink of total
#: internal reflection (``docs/tables.md``, numerics)
FGD_ERROR, FGD_TIR_ERROR = 2e-4, 1.5e-3
#: GGX alpha at or below which a cell is checked against the smooth interface's closed form
ALPHA_SMOOTH = 1e-6
#: the floor of every combined standard error (rounding, and a cell without spread)
EXACT = 1e-6
#: cells listed per failing check
LISTED = 20


def z_cells(cells: int) -> float:
    """Standard errors within which every one of ``cells`` cells must lie for a false-alarm
    probability of P_FALSE_ALARM over the whole table (Bonferroni)."""
    return float(stats.norm.isf(P_FALSE_ALARM / (2 * max(cells, 1))))


@dataclass
class CellCheck:
    """One check of a table's cells against a reference (module docstring)."""

    name: str
    reference: str
    cells: int
    passed: bool
    chi2: float | None = None
    limit: float | None = None
    max_z: float = 0.0
    worst: list[int] = field(default_factory=list)
    failures: list[dict[str, Any]] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "reference": self.reference, "cells": self.cells, "passed": self.passed,
                "chi2": self.chi2, "limit": self.limit, "max_z": self.max_z, "worst": self.worst,
                "failures": self.failures}

    def line(self) -> str:
        """One line for the terminal."""
        verdict = "passes" if self.passed else "FAILS"
        chi = "" if self.chi2 is None else f", chi2 {self.chi2:.1f} over {self.cells} cells (limit {self.limit:.1f})"
        return (f"check {self.name}: {verdict} ({self.reference}; largest deviation {self.max_z:.2f} standard "
                f"errors at {tuple(self.worst)}{chi}"
                + (f"; {len(self.failures)} cell(s) beyond" if self.failures else "") + ")")


def compare(name: str, reference_words: str, values: np.ndarray, stderr: np.ndarray, reference: np.ndarray,
            ref_error: np.ndarray, where: np.ndarray | None = None) -> CellCheck | None:
    """A :class:`CellCheck` of ``values`` against ``reference`` on the cells ``where`` (all by
    default); None if no cell is selected."""
    sel = np.ones(values.shape, dtype=bool) if where is None else np.array(where, dtype=bool)
    sel &= np.isfinite(reference)
    n = int(np.count_nonzero(sel))
    if n == 0:
        return None
    sigma = np.sqrt(stderr ** 2 + ref_error ** 2 + EXACT ** 2)
    dev = values - reference
    z = np.where(sel, dev / sigma, 0.0)
    limit_z = z_cells(n)
    bad = sel & (np.abs(z) > limit_z)
    chi2 = float(np.sum(z[sel] ** 2))
    limit = float(stats.chi2.isf(P_FALSE_ALARM, n))
    worst = [int(i) for i in np.unravel_index(int(np.argmax(np.where(sel, np.abs(z), -1.0))), values.shape)]
    failures = [{"cell": [int(i) for i in idx], "value": float(values[idx]), "stderr": float(stderr[idx]),
                 "reference": float(reference[idx]), "z": float(z[idx])} for idx in zip(*np.nonzero(bad))][:LISTED]
    passed = not bad.any() and chi2 <= limit
    return CellCheck(name, reference_words, n, bool(passed), chi2, limit, float(np.max(np.abs(z[sel]))), worst,
                     failures)


# --------------------------------------------------------------------------- references

def _eta(defn: Definition, params: dict[str, np.ndarray]) -> np.ndarray:
    eta = params["ior"]
    return 1.0 / eta if defn.interface.get("side", "outside") == "inside" else eta


def _quadrature_albedo(defn: Definition, mus: np.ndarray, alpha: float, eta: float,
                       quad: tuple[int, int]) -> np.ndarray:
    """The single-scattering albedo (the definition's part) at the cosines ``mus`` of one interface."""
    hc = defn.masking == "height-correlated"
    fresnel = defn.interface["fresnel"]
    if fresnel == "white":
        return direct(mus, alpha, kind="white", height_correlated=hc, n_z=quad[0], n_phi=quad[1])
    if fresnel == "conductor":
        return fgd_direct_many(mus, alpha, eta, float(defn.interface["extinction"]), hc)
    both = direct(mus, alpha, eta, kind="dielectric", height_correlated=hc, n_z=quad[0], n_phi=quad[1])
    if defn.part == "both":
        return both
    r = fgd_direct_many(mus, alpha, eta, 0.0, hc)
    return r if defn.part == "reflected" else both - r


def reference_values(defn: Definition, quad: tuple[int, int] = QUAD, coarse: tuple[int, int] = QUAD_COARSE
                     ) -> tuple[np.ndarray, np.ndarray, str] | None:
    """The quadrature's value of every cell of a single-scattering ``albedo`` or
    ``albedo-average`` table, its error bound (the difference from the ``coarse`` rule, or the
    FGD's stated error) and what it is, in words; None for the other tables. ``quad``: the albedo
    quadrature's (cap heights, azimuths)."""
    if defn.quantity not in ("albedo", "albedo-average") or defn.multiple_scattering:
        return None
    params = cell_parameters(defn)
    shape = defn.shape
    fresnel = defn.interface["fresnel"]
    alpha = params["roughness"]
    eta = _eta(defn, params) if fresnel != "white" else np.ones(shape)
    if defn.quantity == "albedo-average":
        x, w = np.polynomial.legendre.leggauss(AVERAGE_REFERENCE_NODES)
        mu_nodes, weights = 0.5 * (x + 1.0), w * 0.5 * (x + 1.0)
    ref, err = np.empty(shape), np.empty(shape)
    keys = np.stack([alpha, eta], axis=-1).reshape(-1, 2)
    flat_ref, flat_err = ref.reshape(-1), err.reshape(-1)
    mu_flat = params["mu"].reshape(-1) if "mu" in params else None
    fgd = fresnel == "conductor" or (fresnel == "dielectric" and defn.part != "both")
    for key in np.unique(keys, axis=0):
        cells = np.flatnonzero(np.all(keys == key, axis=1))
        a, e = float(key[0]), float(key[1])
        if a == 0.0:     # a smooth interface: no quadrature (its closed form is the fresnel check)
            flat_ref[cells], flat_err[cells] = np.nan, 0.0
            continue
        mus = mu_nodes if defn.quantity == "albedo-average" else mu_flat[cells]
        fine = _quadrature_albedo(defn, mus, a, e, quad)
        if fgd:
            tir = fresnel == "dielectric" and e < 1.0
            bound = np.full(mus.shape, FGD_TIR_ERROR if tir else FGD_ERROR)
            if defn.part == "transmitted":   # both - reflected: the albedo quadrature's error too
                both = direct(mus, a, e, kind="dielectric", height_correlated=defn.masking == "height-correlated",
                              n_z=coarse[0], n_phi=coarse[1])
                bound = bound + np.abs(both - direct(mus, a, e, kind="dielectric",
                                                     height_correlated=defn.masking == "height-correlated",
                                                     n_z=quad[0], n_phi=quad[1]))
        else:
            bound = np.abs(fine - _quadrature_albedo(defn, mus, a, e, coarse))
        if defn.quantity == "albedo-average":
            flat_ref[cells] = np.sum(weights * fine)
            flat_err[cells] = np.sum(weights * bound)
        else:
            flat_ref[cells] = fine
            flat_err[cells] = bound
    what = {"white": "microfacet_albedo.direct (F = 1)", "conductor": "fgd_direct_many (Belcour's FGD)",
            "dielectric": "microfacet_albedo.direct (R + T)" if defn.part == "both" else
            "fgd_direct_many (R)" + (" and microfacet_albedo.direct (R + T)" if defn.part == "transmitted" else "")}
    words = f"quadrature: models.tables.{what[fresnel]}, {quad[0]} x {quad[1]} nodes"
    if defn.quantity == "albedo-average":
        words += f", {AVERAGE_REFERENCE_NODES}-point Gauss-Legendre in mu"
    return ref, err, words


def smooth_values(defn: Definition) -> tuple[np.ndarray, np.ndarray] | None:
    """The smooth interface's closed form at every cell of an ``albedo`` table and the cells it
    applies to (GGX alpha <= ALPHA_SMOOTH); None for the other tables or when no cell is that smooth."""
    if defn.quantity != "albedo":
        return None
    params = cell_parameters(defn)
    sel = params["roughness"] <= ALPHA_SMOOTH
    if not sel.any():
        return None
    mu = params["mu"]
    fresnel = defn.interface["fresnel"]
    if fresnel == "white" or (fresnel == "dielectric" and defn.part == "both"):
        return np.ones(defn.shape), sel
    if fresnel == "conductor":
        return np_fresnel_conductor(mu, params["ior"], float(defn.interface["extinction"])), sel
    f = np_fresnel_dielectric(mu, _eta(defn, params))
    return (f if defn.part == "reflected" else 1.0 - f), sel


def coat_closed_form(defn: Definition) -> tuple[np.ndarray, np.ndarray, str] | None:
    """Closed forms of coat tables (``docs/lut.md`` section 7): an index-matched coat is absent
    (darkening 1; effective roughness the base's alpha, single scattering only: the estimator's
    model lobe is the single-scattering one); a smooth coat (index n) over a Lambertian of albedo
    ``E_b`` sends ``E_int = E_b (1 - F(mu)) g / (1 - E_b (1 - g))`` back up, ``g = (1 - E_F(n)) / n^2``
    the escaping fraction of the light the base diffuses (a geometric series), so its darkening is
    ``g / (1 - E_b (1 - g))`` (``darkening = "albedo"``), or that internal albedo over the
    production estimator's binned ``P = E_b sum_rows (1 - F(mu_row)) (sin^2 theta_hi - sin^2 theta_lo)``;
    a white base (albedo 1) under a coat, every interface scattering multiply, absorbs nothing, so
    ``E = 1`` and its darkening is 1 (``darkening = "albedo"``)."""
    if defn.quantity not in ("coat-darkening", "coat-roughness"):
        return None
    params = cell_parameters(defn)
    n = params["coat_ior"]
    ref = np.full(defn.shape, np.nan)
    matched = n == 1.0
    if defn.quantity == "coat-roughness":
        if defn.multiple_scattering:
            return None
        ref[matched] = params["base_roughness"][matched]
        return (ref, matched, "an index-matched coat is absent: the base's own alpha") if matched.any() else None
    ref[matched] = 1.0
    words = ["an index-matched coat is absent: 1"]
    white = (params["base_albedo"] == 1.0) & ~matched
    if defn.darkening == "albedo" and defn.multiple_scattering and white.any():
        ref[white] = 1.0     # nothing absorbs: E = 1 = E_coat + (1 - E_coat) Delta 1
        words.append("a white base under a coat, scattering multiply, loses nothing: 1")
    smooth = (params["coat_roughness"] == 0.0) & ~matched & ~white
    if defn.base["kind"] == "lambertian" and smooth.any():
        nt = defn.resolution[0]
        edges = np.radians(np.linspace(0.0, 90.0, nt + 1))
        centre = np.cos(0.5 * (edges[:-1] + edges[1:]))
        ring = np.sin(edges[1:]) ** 2 - np.sin(edges[:-1]) ** 2
        for idx in zip(*np.nonzero(smooth)):
            eta, e_b, mu = float(n[idx]), float(params["base_albedo"][idx]), float(params["mu"][idx])
            g = (1.0 - fresnel_average(eta)) / (eta * eta)
            if defn.darkening == "albedo":
                ref[idx] = g / (1.0 - e_b * (1.0 - g))
                continue
            internal = e_b * (1.0 - np_fresnel_dielectric(mu, eta)) * g / (1.0 - e_b * (1.0 - g))
            predicted = e_b * np.sum((1.0 - np_fresnel_dielectric(centre, eta)) * ring)
            ref[idx] = internal / predicted
        words.append("a smooth coat over a Lambertian: the geometric series")
    sel = np.isfinite(ref)
    return (ref, sel, "; ".join(words)) if sel.any() else None


def check_table(result: LutResult, reference: tuple[np.ndarray, np.ndarray, str] | None = None) -> list[CellCheck]:
    """Every check that applies to ``result`` (module docstring); ``reference``: the quadrature's
    values (:func:`reference_values`) when the caller has them already."""
    d = result.definition
    v, se = result.values, result.stderr
    out: list[CellCheck | None] = []
    ref = reference if reference is not None else reference_values(d)
    if ref is not None:
        out.append(compare("quadrature", ref[2], v, se, ref[0], ref[1]))
    smooth = smooth_values(d)
    if smooth is not None:
        out.append(compare("fresnel", f"the smooth interface's closed form at GGX alpha <= {ALPHA_SMOOTH:g}",
                           v, se, smooth[0], np.zeros(v.shape), smooth[1]))
    conserves = d.quantity in ("albedo", "albedo-average") and d.multiple_scattering and (
        d.interface["fresnel"] == "white" or (d.interface["fresnel"] == "dielectric" and d.part == "both"))
    if conserves:
        out.append(compare("energy", "a multiple-scattering interface that absorbs nothing keeps everything: 1",
                           v, se, np.ones(v.shape), np.zeros(v.shape)))
    closed = coat_closed_form(d)
    if closed is not None:
        out.append(compare("closed-form", closed[2], v, se, closed[0], np.zeros(v.shape), closed[1]))
    return [c for c in out if c is not None]


# --------------------------------------------------------------------------- a published table

def read_c_array(path: str | Path, name: str) -> np.ndarray:
    """The numbers of the C array ``name`` in the source file at ``path`` (``float name[N] = {...};``,
    a trailing ``f`` allowed), flattened. Raises :class:`LutError` naming the file and the array."""
    try:
        text = Path(path).read_text(encoding="utf-8", errors="replace")
    except OSError as e:
        raise LutError(f"--published: {path}: cannot read: {e.strerror or e}") from None
    text = re.sub(r"/\*.*?\*/", " ", text, flags=re.S)
    text = re.sub(r"//[^\n]*", " ", text)
    m = re.search(rf"\b{re.escape(name)}\s*(\[[^\]]*\]\s*)+=\s*\{{(.*?)\}}\s*;", text, flags=re.S)
    if m is None:
        raise LutError(f"--published: {path}: no array {name} (float {name}[N] = {{...}};)")
    items = [x.strip() for x in m.group(2).replace("{", " ").replace("}", " ").split(",") if x.strip()]
    try:
        return np.array([float(x.rstrip("fF")) for x in items])
    except ValueError as e:
        raise LutError(f"--published: {path}: {name}: not a list of numbers ({e})") from None


def compare_published(result: LutResult, published: np.ndarray, decimals: int,
                      reference: tuple[np.ndarray, np.ndarray, str] | None = None) -> dict[str, Any]:
    """Where a published table is off by more than its own precision (half a unit of its last
    decimal) and, in combination with it, our standard error (``beyond_ours``: more than
    :func:`z_cells` combined standard errors); with a quadrature ``reference`` (:func:`reference_values`)
    also where it is off from the quadrature by more than its precision plus twice the
    quadrature's error bound (``beyond_quadrature``). Each list is sorted by the size of its
    difference, largest first."""
    d = result.definition
    if published.size != d.cells:
        raise LutError(f"--published: {d.published.array if d.published else 'the array'} holds {published.size} "
                       f"numbers; the table has {d.cells} cells ({' x '.join(map(str, d.shape))})")
    p = published.reshape(d.shape)
    half = 0.5 * 10.0 ** (-decimals)
    dev = p - result.values
    sigma = np.sqrt(result.stderr ** 2 + half ** 2)
    z = dev / sigma
    limit = z_cells(d.cells)

    def cells(mask: np.ndarray, extra: dict[str, np.ndarray], by: np.ndarray) -> list[dict[str, Any]]:
        order = np.argsort(-np.abs(by[mask]), kind="stable")
        idx = [tuple(int(i) for i in t) for t in zip(*np.nonzero(mask))]
        return [dict({"cell": list(idx[k]), "published": float(p[idx[k]]), "value": float(result.values[idx[k]]),
                      "stderr": float(result.stderr[idx[k]])}, **{n: float(a[idx[k]]) for n, a in extra.items()})
                for k in order]

    out: dict[str, Any] = {
        "cells": d.cells, "precision": half, "max_abs_difference": float(np.max(np.abs(dev))),
        "rms_difference": float(np.sqrt(np.mean(dev ** 2))), "max_z": float(np.max(np.abs(z))), "z_limit": limit,
        "beyond_ours": cells(np.abs(z) > limit, {"z": z}, dev),
    }
    if reference is not None:
        ref, err, words = reference
        dq = p - ref
        bad = np.abs(dq) > half + 2.0 * err
        out["quadrature"] = words
        out["max_abs_difference_quadrature"] = float(np.max(np.abs(dq)))
        out["beyond_quadrature"] = cells(bad, {"quadrature": ref, "quadrature_error": err}, dq)
    return out


# --------------------------------------------------------------------------- production formulas scored

def _scored(result: LutResult, predictions: dict[str, np.ndarray], tolerance: float,
            params: dict[str, np.ndarray]) -> dict[str, Any]:
    v, se = result.values, result.stderr
    out: dict[str, Any] = {"tolerance": tolerance, "formulas": {}}
    for name, pred in predictions.items():
        err = pred - v
        fails = (np.abs(err) > tolerance) & (np.abs(err) > Z_TOL * se)
        worst = tuple(int(i) for i in np.unravel_index(int(np.argmax(np.abs(err))), v.shape))
        out["formulas"][name] = {
            "rmse": float(np.sqrt(np.mean(err ** 2))), "max_abs_error": float(np.max(np.abs(err))),
            "worst_cell": list(worst), "failing_cells": int(np.count_nonzero(fails)), "cells": int(v.size),
            "failures": [{"cell": [int(i) for i in idx], "measured": float(v[idx]), "stderr": float(se[idx]),
                          "predicted": float(pred[idx]), **{k: float(a[idx]) for k, a in params.items()}}
                         for idx in zip(*np.nonzero(fails))],
        }
    return out


def score_darkening(result: LutResult) -> dict[str, Any]:
    """OpenPBR's coat darkening formulas on a ``coat-darkening`` table: the specification's
    (v1.1.1, ``(1 - K) / (1 - E_b K)``), the corrected numerator of issue #269 (``(1 - K_r) /
    (1 - E_b K)``) and the node graph's (MaterialX 1.39.5, ``K = 1 - (1 - F0) / n^2``), each
    with ``K_s`` at the cell's incident cosine, ``E_b`` the base's albedo (a conductor's F0 in
    air), ``r_b`` the conductor's perceptual roughness (1 for a Lambertian base); over a
    Lambertian also Standard Surface's ``base_color ** (1 + coat_affect_color)`` with
    ``coat_affect_color = 1``, a factor ``E_b``. A cell fails a formula where it is off by more than
    the tolerance and by more than Z_TOL standard errors."""
    from models.production.openpbr import coat_darkening, coat_darkening_spec
    d = result.definition
    if d.quantity != "coat-darkening":
        raise LutError(f"score: a {d.quantity} table is not a coat darkening")
    p = cell_parameters(d)
    n, e_b, mu = p["coat_ior"], p["base_albedo"], p["mu"]
    r_b = np.sqrt(p["base_roughness"]) if d.base["kind"] == "conductor" else np.ones(d.shape)
    predictions = {
        "openpbr-1.1": coat_darkening_spec(n, e_b, r_b, mu, corrected=False),
        "openpbr-corrected-269": coat_darkening_spec(n, e_b, r_b, mu, corrected=True),
        "openpbr-node-graph": coat_darkening(n, e_b),
    }
    if d.base["kind"] == "lambertian":   # Standard Surface darkens a diffuse base only
        from models.production.standard_surface import coat_affected_color
        predictions["standard-surface"] = coat_affected_color(e_b) / np.where(e_b > 0, e_b, 1.0)
    shown = {"mu": mu, "coat_ior": n, "base_albedo": e_b, "base_roughness_r": r_b}
    return _scored(result, predictions, d.score_tolerance, shown)


def score_roughness(result: LutResult, tolerance: float = 0.02) -> dict[str, Any]:
    """Coat roughening formulas on a ``coat-roughness`` table (GGX alpha): OpenPBR 1.1's
    (``alpha'^2 = min(1, alpha_b^2 + 2 alpha_c^2)``), OpenPBR pull request #261's and Standard
    Surface's (``coat_affect_roughness = 1``)."""
    from models.production.openpbr import coat_roughening, coat_roughening_pr261
    from models.production.standard_surface import coat_affected_roughness
    d = result.definition
    if d.quantity != "coat-roughness":
        raise LutError(f"score: a {d.quantity} table is not a coat roughness")
    p = cell_parameters(d)
    r_b, r_c, n = np.sqrt(p["base_roughness"]), np.sqrt(p["coat_roughness"]), p["coat_ior"]
    predictions = {
        "openpbr-1.1": coat_roughening(r_b, r_c) ** 2,
        "openpbr-pr261": coat_roughening_pr261(r_b, r_c, n) ** 2,
        "standard-surface": coat_affected_roughness(r_b, r_c) ** 2,
    }
    shown = {"coat_ior": n, "coat_alpha": p["coat_roughness"], "base_alpha": p["base_roughness"]}
    return _scored(result, predictions, tolerance, shown)


__all__ = ["P_FALSE_ALARM", "Z_TOL", "QUAD", "ALPHA_SMOOTH", "EXACT", "z_cells", "CellCheck", "compare",
           "reference_values", "smooth_values", "coat_closed_form", "check_table", "read_c_array",
           "compare_published", "score_darkening", "score_roughness"]
