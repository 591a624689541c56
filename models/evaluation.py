"""Evaluate models against a simulated file: which side, which models, errors, saved slices.

The comparison side follows Bati 2019: a stack that transmits (a slab) is judged on its BTDF,
every other stack on its BRDF. For a BRDF, "internal" drops the reflection off the top interface
(bounce order 1 in the reference, the top lobe in the model); for a BTDF "internal" and "total"
are the same comparison.

On a polarized file (``docs/polarization.md``, "Models on polarized files") every model keeps its
intensity errors against the file's ``value`` (``M00``), and a polarized model
(:attr:`models.base.Model.polarized`) also gets the errors of its Mueller matrices element by element
(:func:`models.compare.errors.mueller_errors`, ``Evaluation.mueller``); a model that gives none is
listed in ``Evaluation.intensity_only`` with why.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from goniometer.files import slices as store
from goniometer.run.results import SimulationResult
from goniometer.stack import Interface, Stack
from models import registry
from models.compare import errors
from models.base import ModelError, ModelFailure, failure, require_slices
from models.compare.errors import Coverage, require_cells
from models.compare.integrate import ModelSlices, MuellerSlices, integrate, integrate_mueller

MODEL_SLICES_FORMAT = "goniometer.model-slices"


def comparison_side(stack: Stack) -> str:
    """``"btdf"`` for stacks that transmit (slabs), ``"brdf"`` otherwise."""
    return "btdf" if stack.transmits else "brdf"


@dataclass
class Evaluation:
    """Errors of every evaluated model, the reasons others were skipped and the failures of those
    that failed (``failed``: model -> one line, :class:`models.base.ModelFailure`)."""

    material: str
    category: str
    side: str
    errors: dict[str, dict] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    slices: dict[str, ModelSlices] = field(default_factory=dict)
    fits: dict[str, dict] = field(default_factory=dict)
    approximations: dict[str, str] = field(default_factory=dict)
    #: what the reference is when it is not a simulation (a measured file, a spectral run)
    reference_note: str | None = None
    failed: dict[str, str] = field(default_factory=dict)
    #: the cells every error is summed over (models.compare.errors.Coverage)
    coverage: Coverage | None = None
    #: the reference is a measurement (docs/measured.md): no bounce orders, "internal" is the whole BRDF
    measured: bool = False
    #: the reference is polarized: its judged side holds Mueller matrices (docs/polarization.md, "Models on
    #: polarized files")
    polarized: bool = False
    #: polarized models' per-element errors (models.compare.errors.mueller_errors), model -> object
    mueller: dict[str, dict] = field(default_factory=dict)
    #: their integrated Mueller matrices
    mueller_slices: dict[str, MuellerSlices] = field(default_factory=dict)
    #: on a polarized reference, the evaluated models judged on the intensity only, and why
    intensity_only: dict[str, str] = field(default_factory=dict)

    def fail(self, name: str, e: ModelFailure) -> None:
        """Record that model ``name`` failed (its one line under ``failed``; no note of it kept)."""
        self.failed[name] = e.reason
        self.approximations.pop(name, None)

    @property
    def internal_compares(self) -> str:
        """What the ``internal`` errors compare, in words (``docs/models.md`` §3)."""
        if self.side == "btdf":
            return "the whole BTDF"
        if self.measured:
            return "the whole BRDF (a measurement has no bounce orders)"
        return "internal paths (order 1 dropped)"

    def to_json(self) -> dict:
        """The object printed by ``gonio evaluate --json`` (``fits``: parameters and convergence of
        fitted models, when any was asked for; ``failed``: model -> why it failed; ``cells``,
        ``cells_total``: the support of every error, as in each error object). On a polarized
        reference only: ``polarized`` (true), ``mueller`` (model -> the per-element errors of
        :func:`models.compare.errors.mueller_errors`) and ``intensity_only`` (model -> why it has
        intensity errors only)."""
        out = {"material": self.material, "category": self.category, "side": self.side,
               "models": self.errors, "skipped": self.skipped, "failed": self.failed}
        if self.polarized:
            out["polarized"] = True
            out["mueller"] = self.mueller
            out["intensity_only"] = self.intensity_only
        if self.coverage is not None:
            out["cells"], out["cells_total"] = self.coverage.cells, self.coverage.cells_total
        if self.fits:
            out["fits"] = self.fits
        if self.approximations:
            out["approximations"] = self.approximations
        if self.reference_note is not None:
            out["reference"] = self.reference_note
        return out


ISOTROPIZE = ("mean",)


def isotropized(stack: Stack, rule: str = "mean") -> Stack:
    """``stack`` with every anisotropic interface replaced by an isotropic one of roughness
    (alpha_x + alpha_y) / 2 (rule "mean"), its rotation dropped: how an isotropic model is fed
    an anisotropic material when asked to (``--isotropize mean``)."""
    if rule not in ISOTROPIZE:
        raise ModelError(f"isotropize: {rule!r} is not one of {', '.join(ISOTROPIZE)}")
    layers = []
    for x in stack.layers:
        if isinstance(x, Interface) and x.is_anisotropic:
            x = Interface(0.5 * sum(x.alpha_xy), x.ior, x.extinction)
        layers.append(x)
    return Stack(stack.name, tuple(layers), stack.category)


def evaluate(reference: SimulationResult, names: list[str] | None = None, s: int = 5,
             progress=None, isotropize: str | None = None) -> Evaluation:
    """Integrate models onto ``reference`` and compute their errors.

    ``names=None`` evaluates every registered model (built-in and plugins, :mod:`models.registry`)
    that supports the stack and side and lists the others as skipped with their reason; ``names``
    may hold adapter specs (``python:MODULE:NAME``, ``mitsuba:FILE``, :mod:`models.adapters`);
    explicitly named models that cannot represent the stack raise :class:`ModelError` (a user asked
    for something impossible), and only the named ones appear in the result. Fitted models
    (``hp15-fit``, ``ggx1-fit``, ``ggx2-fit``) are fitted to this file's BRDF when named (they take
    seconds to minutes) and listed as skipped when no model is named. ``isotropize="mean"`` lets
    isotropic models evaluate an anisotropic stack through :func:`isotropized` (recorded in
    ``approximations``); by default they skip it. ``progress(name)`` is called before each model. A
    spectral reference is judged in linear sRGB (:meth:`SimulationResult.rgb`, ``docs/spectral.md``
    section 4) with the models reading the material's RGB equivalent (noted in ``reference_note``).

    A model that fails (:class:`models.base.ModelFailure`: its own code raised, or it returned
    non-finite values) is recorded under ``failed`` and the others go on. A reference without a
    valid cell on the judged side raises :class:`models.compare.errors.NoCellsError` before any
    model runs; ``coverage`` holds the cells every error is summed over (``docs/models.md`` §3).
    """
    require_slices(reference)
    spectral_note = None
    if reference.settings.spectral:
        spectral_note = (f"spectral reference ({reference.settings.wavelength_bins} wavelength bins) judged in linear "
                         f"sRGB (D65, CIE 1931); the models read the material's RGB equivalent (docs/spectral.md)")
        reference = reference.rgb()
    stack = reference.stack
    side = comparison_side(stack)
    if (side == "brdf" and reference.brdf is None) or (side == "btdf" and reference.btdf is None):
        raise ModelError(f"the file has no {side.upper()} slices, which a {stack.base}-base stack is judged on")
    available = registry.models_for(names)
    fitted = registry.fitted_models()
    if names:
        unknown = [n for n in names if n not in available and n not in fitted]
        if unknown:
            raise registry.UnknownModel(unknown[0], [*available, *fitted])
    result = Evaluation(stack.name, stack.category, side)
    if spectral_note is not None:
        result.reference_note = spectral_note
    sd = reference.brdf if side == "brdf" else reference.btdf
    # a measurement has no bounce orders: "internal" then compares the whole BRDF too
    result.measured = "measured" in reference.extra
    if result.measured:
        result.reference_note = (f"measured reference {reference.extra['measured']['file']} "
                                 f"({reference.extra['measured']['resampling']}; {reference.extra['measured']['subcells']}"
                                 f"x{reference.extra['measured']['subcells']} sub-cells per cell): no standard errors "
                                 f"(noise floor unknown) and no bounce orders ('internal' compares the whole BRDF)")
    result.coverage = require_cells(reference, side)
    cells_total = result.coverage.cells_total
    result.polarized = sd.mueller is not None
    anisotropic = stack.is_anisotropic
    for name, model in available.items():
        if names and name not in names:
            continue
        if not names and model.on_request:
            result.skipped[name] = model.on_request_note()
            continue
        model_stack = stack
        if anisotropic and isotropize and not model.anisotropic:
            model_stack = isotropized(stack, isotropize)
            result.approximations[name] = (f"isotropic model fed the anisotropic interfaces' {isotropize} "
                                           f"roughness (alpha_x + alpha_y) / 2")
        try:
            reason = model.reason(model_stack)
        except ModelFailure as e:
            result.fail(name, e)
            continue
        if reason is not None and anisotropic and not model.anisotropic and not isotropize:
            reason += "; --isotropize mean evaluates it with the mean roughness"
        if reason is None and side not in model.sides:
            reason = f"models the {'/'.join(x.upper() for x in model.sides)}; this stack is judged on its {side.upper()}"
        if reason is not None:
            if names:
                raise ModelError(f"{name}: {reason}")
            result.skipped[name] = reason
            continue
        if model.approximation:
            result.approximations[name] = model.approximation
        if progress is not None:
            progress(name)
        try:
            ms = integrate(model, reference, side, s, stack=model_stack)
        except ModelFailure as e:
            result.fail(name, e)
            continue
        result.slices[name] = ms
        result.errors[name] = errors.compare(sd, ms, drop_first_order=(side == "brdf") and not result.measured,
                                             cells_total=cells_total)
        if result.polarized:
            _judge_mueller(result, model, reference, sd, side, s, model_stack, cells_total)
    for name in fitted:
        if not names:
            result.skipped[name] = f"fitted to the file on request only (--model {name})"
            continue
        if name not in names:
            continue
        if side != "brdf":
            raise ModelError(f"{name}: fitted models are BRDF models; this stack is judged on its {side.upper()}")
        if progress is not None:
            progress(name)
        try:
            fr, ms = _fit(reference, name, s)
        except ModelFailure as e:
            result.fail(name, e)
            continue
        result.slices[name] = ms
        # a fit has no top/internal split: both parts compare the whole BRDF
        result.errors[name] = errors.compare(sd, ms, drop_first_order=False, cells_total=cells_total)
        result.fits[name] = {"params": fr.params, "converged": fr.converged, "message": fr.message,
                             "n_cells": fr.n_cells}
        if result.polarized:
            result.intensity_only[name] = "a fitted scalar model: it gives intensities, not Mueller matrices"
    return result


def _judge_mueller(result: Evaluation, model, reference: SimulationResult, sd, side: str, s: int, stack: Stack,
                   cells_total: int) -> None:
    """On a polarized reference, the per-element errors of ``model``'s Mueller matrices, or why it
    is judged on the intensity only; a model whose Mueller matrices (or their note) fail is recorded
    under ``failed``, its intensity errors kept."""
    try:
        reason = model.mueller_reason(stack)
        if reason is not None:
            result.intensity_only[model.name] = reason
            return
        mu = integrate_mueller(model, reference, side, s, stack=stack)
        try:
            note = model.mueller_note(stack)
        except Exception as e:  # noqa: BLE001 -- the model's own code
            raise failure(model.name, "mueller_note", e) from None
    except ModelFailure as e:     # (its intensity errors and their notes stand)
        result.failed[model.name] = f"its Mueller matrices: {e.reason}"
        return
    result.mueller_slices[model.name] = mu
    result.mueller[model.name] = errors.mueller_errors(sd, mu, cells_total)
    if note:
        result.mueller[model.name]["note"] = str(note)


def _fit(reference: SimulationResult, name: str, s: int):
    """The fit of the fitted model ``name`` to ``reference`` and its slices; whatever the fit or the
    fitted model raises but a refusal (:class:`ModelError`) is the fitted model's failure."""
    from models.fitted import fit
    try:
        fr = fit(reference, name, errors=False)
        return fr, integrate(fr.model, reference, "brdf", s)
    except ModelError:   # a refusal, or already the model's failure
        raise
    except Exception as e:  # noqa: BLE001 -- a fit that breaks is that fitted model's failure
        raise failure(name, "the fit", e) from None


def save_slices(path: str | Path, reference: SimulationResult, evaluation: Evaluation) -> Path:
    """Write the integrated model slices, laid out like the reference (atomic).

    Format ``goniometer.model-slices`` version 1: ``/material``, ``/incident`` as in the
    reference; per model a group ``/<model>/<side>`` with ``value`` (= top + internal), ``top``,
    ``internal`` (M, 3, n_theta, n_phi; 1/sr) and the reference's ``mask`` and
    ``proj_solid_angle``; attribute ``subcells``; for a stochastic model also ``top_stderr`` and
    ``internal_stderr``; for a polarized model judged on a polarized reference ``mueller``
    (M, 3, n_theta, n_phi, 4, 4; 1/sr, the reference's s/p frames). The group of a model is named
    by :func:`group_name` (an adapter spec's ``/`` escaped).
    """
    p = store.check_writable(path)
    sd = reference.brdf if evaluation.side == "brdf" else reference.btdf
    with store.atomic_path(p) as tmp:
        with h5py.File(tmp, "w") as f:
            store.write_header(f, MODEL_SLICES_FORMAT, reference.stack, reference.theta_deg, reference.phi_deg)
            f.attrs["reference_side"] = evaluation.side
            for name, ms in evaluation.slices.items():
                g = f.create_group(group_name(name))
                w = store.SliceGroupWriter(g, evaluation.side, ms.grid, reference.theta_deg,
                                           phi_deg=reference.phi_deg)
                w.group.attrs["subcells"] = ms.subcells
                w.put("value", ms.total, store.CELLS, "1/sr", long_name=f"{name} cell mean",
                      description="the model integrated over the reference's cells (top + internal)")
                w.put("top", ms.top, store.CELLS, "1/sr", long_name=f"{name} top lobe",
                      description="lobe reflected off the top interface")
                w.put("internal", ms.internal, store.CELLS, "1/sr", long_name=f"{name} internal part",
                      description="everything but the top lobe")
                w.put("mask", sd.mask, store.MAPS, "1", long_name="cell valid for comparisons",
                      description=store.MASK_DESCRIPTION)
                w.put("proj_solid_angle", sd.proj_solid_angle, store.MAPS, "sr")
                for part in ("top", "internal"):
                    if ms.stochastic:
                        w.put(f"{part}_stderr", ms.stderr(part), store.CELLS, "1/sr",
                              long_name=f"{name} {part} standard error",
                              description="the stochastic model's own standard error of the cell mean")
                mu = evaluation.mueller_slices.get(name)
                if mu is not None:
                    w.mueller_scales()
                    w.put("mueller", mu.mueller, store.CELLS + ("mueller_row", "mueller_col"), "1/sr",
                          long_name=f"{name} Mueller matrix cell mean",
                          description="the polarized model's Mueller matrices integrated over the reference's cells, "
                                      "in the reference's s/p frames (docs/polarization.md)")
    return p


def group_name(model: str) -> str:
    """The HDF5 group name of ``model`` in the files that store per-model data: the name itself,
    with ``%`` and ``/`` written ``%25`` and ``%2F`` (adapter specs hold paths; registered model
    names hold neither character, so their groups keep their names)."""
    return model.replace("%", "%25").replace("/", "%2F")


def read_slices(path: str | Path, model: str, side: str) -> dict[str, np.ndarray]:
    """Read one model's saved slices (``value``, ``top``, ``internal``, ``mask``, ``proj_solid_angle``,
    and ``mueller`` when the file holds it)."""
    with h5py.File(path, "r") as f:
        if f.attrs.get("format") != MODEL_SLICES_FORMAT:
            raise store.StoreError(f"{path}: not a {MODEL_SLICES_FORMAT} file")
        g = f[f"{group_name(model)}/{side}"]
        keys = ("value", "top", "internal", "mask", "proj_solid_angle") + (("mueller",) if "mueller" in g else ())
        return {k: np.asarray(g[k][()]) for k in keys}
