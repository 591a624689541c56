"""From measurements to the verdict: samples, the specification's and belcour-fwd's predictions, the
held-out split, the fits and the errors (``docs/production.md`` sections 4-6).

Samples. Darkening: one sample per (coated material, colour channel) -- the coat is achromatic, so
each channel is an independent base albedo. Roughening: one sample per coated conductor (channel
mean). The **reference** is the multiple-scattering configurations (energy-conserving interfaces,
what a renderer with energy compensation should match): fits and the summary's headline errors use
them; the single-scattering twins are reported beside them with the same formulas.

Specification: :func:`models.production.openpbr.coat_darkening` and
:func:`models.production.openpbr.coat_roughening` on the OpenPBR inputs of each stack
(:func:`models.production.openpbr_parameters`); roughness compared as GGX alpha (``alpha = r**2``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from models.production.study.fitting_formulas import (DARKENING, ROUGHENING, SPLIT_SEED, Fit, Formula, fit_formula,
                                                heldout_iors, is_heldout, rmse)
from models.production.study.effective import ProductionError
from models.production.study.measure import Measurement
from models.production.openpbr import alpha_from_roughness, coat_darkening, coat_roughening
from models.production.openpbr_coat import OpenPBRParameters

#: the scattering mode of the reference configurations
REFERENCE_SCATTERING = "ms"
CHANNELS = ("R", "G", "B")
QUANTITIES = ("darkening", "roughening")


@dataclass
class Samples:
    """One quantity's samples as columns (1-D arrays of equal length) plus per-sample labels."""

    quantity: str
    names: list[str]
    channel: list[str]
    scattering: list[str]
    columns: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.names)

    def take(self, mask: np.ndarray) -> "Samples":
        idx = np.flatnonzero(mask)
        return Samples(self.quantity, [self.names[i] for i in idx], [self.channel[i] for i in idx],
                       [self.scattering[i] for i in idx], {k: v[idx] for k, v in self.columns.items()})


def _spec_inputs(p: OpenPBRParameters) -> tuple[np.ndarray, float]:
    """OpenPBR's base albedo estimate E_base (RGB) and base metalness of a parameter set."""
    color = np.asarray(p.base_color, dtype=np.float64)
    e_metal = color * p.specular_weight
    return p.base_metalness * e_metal + (1.0 - p.base_metalness) * color, float(p.base_metalness)


def build_samples(measurements: list[Measurement], parameters: dict[str, OpenPBRParameters]) -> dict[str, Samples]:
    """Darkening and roughening samples with the measured value, its stderr, the spec's and belcour-fwd's
    predictions and the formula inputs. ``parameters``: OpenPBR inputs by material name."""
    rows = {q: [] for q in QUANTITIES}
    for m in measurements:
        cfg, p = m.config, parameters[m.name]
        e_base, metal = _spec_inputs(p)
        scat = "ms" if cfg.multiple_scattering else "ss"
        base_alpha = cfg.base_alpha if cfg.base_alpha is not None else 0.0
        spec_d = coat_darkening(p.coat_ior, e_base, p.coat_weight, p.coat_darkening)
        for c in range(3):
            rows["darkening"].append(dict(
                name=m.name, channel=CHANNELS[c], scattering=scat, coat_ior=cfg.coat_ior, coat_alpha=cfg.coat_alpha,
                base_alpha=base_alpha, base_metalness=metal, base_albedo=e_base[c],
                measured=m.darkening.value[c], stderr=m.darkening.stderr[c], spec=float(spec_d[c]),
                belcour=np.nan if m.belcour_darkening is None else m.belcour_darkening[c]))
        if m.roughness is not None:
            spec_a = float(alpha_from_roughness(coat_roughening(p.specular_roughness, p.coat_roughness,
                                                                p.coat_weight)))
            rows["roughening"].append(dict(
                name=m.name, channel="mean", scattering=scat, coat_ior=cfg.coat_ior, coat_alpha=cfg.coat_alpha,
                base_alpha=base_alpha, base_metalness=metal, base_albedo=float(np.mean(e_base)),
                measured=m.roughness.alpha, stderr=m.roughness.stderr, spec=spec_a,
                belcour=np.nan if m.belcour_roughness is None else m.belcour_roughness.alpha,
                belcour_lobe_alpha=np.nan if m.belcour_lobe_alpha is None else m.belcour_lobe_alpha,
                clamped=float(m.roughness.clamped)))
    out = {}
    for q, rs in rows.items():
        keys = [k for k in (rs[0] if rs else {}) if k not in ("name", "channel", "scattering")]
        out[q] = Samples(q, [r["name"] for r in rs], [r["channel"] for r in rs], [r["scattering"] for r in rs],
                         {k: np.array([r[k] for r in rs], dtype=np.float64) for k in keys})
    return out


@dataclass
class QuantityResult:
    """Split, fit and errors of one quantity; ``samples`` carries ``fitted`` and ``heldout`` columns."""

    quantity: str
    samples: Samples                 # every sample (both scatterings), with "fitted" and "heldout"
    fit: Fit | None
    summary: dict


def _errors(s: Samples) -> dict:
    """RMSE of spec, fitted and (where it has values) belcour-fwd over ``s`` (same samples for spec/fitted)."""
    y = s.columns["measured"]
    has_b = np.isfinite(s.columns["belcour"])
    out = {"n": len(s), "spec_rmse": rmse(s.columns["spec"], y), "fitted_rmse": rmse(s.columns["fitted"], y),
           "noise_rms": float(np.sqrt(np.mean(s.columns["stderr"] ** 2))) if len(s) else float("nan"),
           "belcour_n": int(has_b.sum())}
    if has_b.any():
        out["belcour_rmse"] = rmse(s.columns["belcour"][has_b], y[has_b])
        if "belcour_lobe_alpha" in s.columns:
            out["belcour_lobe_alpha_rmse"] = rmse(s.columns["belcour_lobe_alpha"][has_b], y[has_b])
        out["spec_rmse_belcour_samples"] = rmse(s.columns["spec"][has_b], y[has_b])
        out["fitted_rmse_belcour_samples"] = rmse(s.columns["fitted"][has_b], y[has_b])
    return out


def run_quantity(samples: Samples, formula: Formula, held: tuple[float, ...]) -> QuantityResult:
    """Fit ``formula`` on the reference training samples; predict everywhere; errors per split and mode."""
    s = samples
    if len(s) == 0:
        raise ProductionError(f"{s.quantity}: no measured configuration (roughening needs coated conductors)")
    held_mask = np.array([is_heldout(x, held) for x in s.columns["coat_ior"]], dtype=bool)
    ref = np.array([x == REFERENCE_SCATTERING for x in s.scattering], dtype=bool)
    s.columns["heldout"] = held_mask.astype(np.float64)
    train = ref & ~held_mask
    X = {k: s.columns[k] for k in formula.inputs}
    fit = None
    if train.sum() >= len(formula.coefficients):
        fit = fit_formula(formula, {k: v[train] for k, v in X.items()}, s.columns["measured"][train])
        s.columns["fitted"] = fit.predict(X)
    else:
        s.columns["fitted"] = np.full(len(s), np.nan)
    test = ref & held_mask
    head = _errors(s.take(test))
    summary = {
        "spec_rmse": head["spec_rmse"], "fitted_rmse": head["fitted_rmse"],
        "n_train": int(train.sum()), "n_heldout": int(test.sum()),
        "belcour_rmse": head.get("belcour_rmse"), "belcour_n": head["belcour_n"],
        "belcour_lobe_alpha_rmse": head.get("belcour_lobe_alpha_rmse"),
        "spec_rmse_belcour_samples": head.get("spec_rmse_belcour_samples"),
        "fitted_rmse_belcour_samples": head.get("fitted_rmse_belcour_samples"),
        "noise_rms": head["noise_rms"],
        "train": {k: v for k, v in _errors(s.take(train)).items() if k in ("n", "spec_rmse", "fitted_rmse")},
        "formula": fit.expression() if fit else None,
        "coefficients": fit.coefficients() if fit else None,
        "converged": fit.converged if fit else False,
        "units": "darkening factor (dimensionless)" if s.quantity == "darkening" else "GGX alpha",
    }
    by_base = {}
    for base, metal in (("conductor", 1.0), ("lambertian", 0.0)):
        sel = test & (s.columns["base_metalness"] == metal)
        if sel.any():
            by_base[base] = _errors(s.take(sel))
    summary["heldout_by_base"] = by_base
    ss = (~ref) & held_mask
    summary["single_scattering_heldout"] = _errors(s.take(ss)) if ss.any() else None
    return QuantityResult(s.quantity, s, fit, summary)


def run_study(measurements: list[Measurement], parameters: dict[str, OpenPBRParameters],
              seed: int = SPLIT_SEED) -> dict[str, QuantityResult]:
    """Samples, the held-out split over coat indices (seeded), fits and errors of both quantities."""
    samples = build_samples(measurements, parameters)
    held = heldout_iors([m.config.coat_ior for m in measurements], seed=seed)
    return {q: run_quantity(samples[q], f, held) for q, f in (("darkening", DARKENING), ("roughening", ROUGHENING))}


def summary_document(results: dict[str, QuantityResult], measurements: list[Measurement], seed: int,
                     extra: dict | None = None) -> dict:
    """The ``summary.json`` document: one entry per quantity with (at least) ``spec_rmse``,
    ``fitted_rmse``, ``n_train`` and ``n_heldout``, plus the split and provenance."""
    iors = sorted({m.config.coat_ior for m in measurements})
    held = heldout_iors(iors, seed=seed)
    doc = {"format": "goniometer.production-summary", "format_version": 1,
           "reference": "multiple-scattering interfaces (docs/production.md section 4)",
           "split": {"seed": seed, "heldout_coat_ior": list(held),
                     "train_coat_ior": [x for x in iors if not is_heldout(x, held)]}}
    doc.update({q: r.summary for q, r in results.items()})
    if extra:
        doc.update(extra)
    return doc
