"""The reference and the models on one lit sphere: render, expose once, compare, draw
(``gonio render``; ``docs/render.md``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Sequence

import numpy as np

from models import registry
from models.base import ModelError, ModelFailure
from models.render.figure import fill, figure, ring, split, write_png
from models.render.modelbsdf import ModelBSDF, node_step_deg
from models.render.reference import Reference, open_reference
from models.render.sphere import BTDF, RenderError, SphereView, shade_views
from models.render.tonemap import EXPOSURE_RULE, display, exposure, pixel_exposure

REFERENCE = "reference"


@dataclass
class SphereSet:
    """Linear radiance images (size, size, 3) of the reference and the models on one sphere view."""

    view: SphereView
    reference: Reference
    images: dict[str, np.ndarray]
    skipped: dict[str, str] = field(default_factory=dict)
    #: models that failed (:class:`models.base.ModelFailure`): name -> one line
    failed: dict[str, str] = field(default_factory=dict)

    @cached_property
    def _tone(self) -> tuple[float, str | None]:
        """``(exposure, reference_note)``: the reference's exposure and None, or, when the reference
        is black or has no value on the sphere, the models' exposure (the same rule on their pixels;
        1 without any) and why the reference cannot be shown."""
        inside = self.view.inside
        try:
            return exposure(self.images[REFERENCE], inside), None
        except RenderError as e:
            ref = self.images[REFERENCE][inside]
            black = bool(np.isfinite(ref).all(axis=-1).any())
            note = f"the reference is black on this sphere: {dark_reason(self.view)}" if black else str(e)
        try:
            k = pixel_exposure(np.concatenate([self.images[n][inside] for n in self.models]))
        except (RenderError, ValueError):
            k = 1.0
        return k, note

    @property
    def exposure(self) -> float:
        """The one exposure of every panel (:func:`models.render.tonemap.exposure` on the reference;
        on the models when the reference cannot set it, :attr:`reference_note`)."""
        return self._tone[0]

    @property
    def reference_note(self) -> str | None:
        """Why the reference cannot be shown on this sphere (black, or no value anywhere), or None."""
        return self._tone[1]

    def display(self, name: str) -> np.ndarray:
        """Display values of panel ``name`` (sRGB-encoded, NaN where it has no value)."""
        return display(self.images[name], self.exposure)

    def rmse(self, name: str) -> float:
        """RMSE of ``name`` against the reference over the sphere pixels where both have a value,
        in display units before clipping and the OETF (exposure applied; 1 = white); NaN when the
        reference cannot set the exposure (:attr:`reference_note`)."""
        if self.reference_note is not None:
            return float("nan")
        a, b = self.images[name][self.view.inside], self.images[REFERENCE][self.view.inside]
        ok = np.all(np.isfinite(a), axis=-1) & np.all(np.isfinite(b), axis=-1)
        if not ok.any():
            return float("nan")
        return float(np.sqrt(np.mean((self.exposure * (a[ok] - b[ok])) ** 2)))

    def no_value(self, name: str) -> float:
        """Fraction of the sphere's pixels where panel ``name`` has no value."""
        px = self.images[name][self.view.inside]
        return float(np.mean(~np.all(np.isfinite(px), axis=-1)))

    @property
    def models(self) -> list[str]:
        return [n for n in self.images if n != REFERENCE]

    def to_json(self) -> dict:
        """What ``gonio render --json`` prints (an RMSE without any common pixel is null)."""
        def num(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None
        return {"light_angle_deg": self.view.light_angle_deg, "size": self.view.size, "side": self.view.side,
                "material": self.reference.stack.name, "reference": self.reference.description,
                "exposure": self.exposure, "reference_note": self.reference_note,
                "no_value_fraction": self.no_value(REFERENCE),
                "models": {n: {"rmse": num(self.rmse(n)), "no_value_fraction": self.no_value(n)} for n in self.models},
                "skipped": dict(self.skipped), "failed": dict(self.failed)}


def model_names(names: Sequence[str] | None) -> list[str] | None:
    """``names`` checked against the registry (``["all"]``: every analytic model, None: none);
    adapter specs (``python:MODULE:NAME``, ``mitsuba:FILE``) are resolved to check them. ModelError
    naming the known ones for an unknown name, or the spec and its reason for a bad spec."""
    if not names:
        return []
    if list(names) == ["all"]:
        return None
    known = registry.all_models()
    for n in names:
        if registry.is_spec(n):
            registry.get(n)
        elif n not in known:
            raise registry.UnknownModel(n, [*known, "all"])
    return list(dict.fromkeys(names))


def render_spheres(reference: Reference, models: Sequence[str] | None, view: SphereView) -> SphereSet:
    """The reference and ``models`` (names; None: every model of the registry) on ``view``. Models
    that refuse the stack or the side are skipped with their reason; a model that fails
    (:class:`models.base.ModelFailure`) is recorded under ``failed`` and the others are rendered."""
    return render_views(reference, models, [view])[0]


def render_views(reference: Reference, models: Sequence[str] | None, views: Sequence[SphereView]) -> list[SphereSet]:
    """:func:`render_spheres` for several views at once: each model is evaluated once per light node
    for all of them (nodes spaced for the largest view, :func:`models.render.modelbsdf.node_step_deg`)."""
    views = list(views)
    for view in views:
        if view.side != reference.side:
            raise ModelError(f"view side {view.side} differs from the reference's {reference.side}")
    images = {REFERENCE: shade_views(views, reference.bsdf)}
    skipped: dict[str, str] = {}
    failed: dict[str, str] = {}
    step = min(node_step_deg(v.size) for v in views)
    for name in (list(registry.all_models()) if models is None else models):
        try:
            f = ModelBSDF(registry.get(name), reference.stack, reference.side, step)
            images[name] = shade_views(views, f)
        except ModelFailure as e:
            failed[name] = e.reason
        except ModelError as e:
            msg = str(e)
            skipped[name] = msg[len(name) + 2:] if msg.startswith(f"{name}: ") else msg
    return [SphereSet(view, reference, {n: imgs[k] for n, imgs in images.items()}, dict(skipped), dict(failed))
            for k, view in enumerate(views)]


def dark_reason(view: SphereView) -> str:
    """Why a reference with values can be black on ``view``: where the peak of a smooth material is
    (``docs/render.md`` 6)."""
    a = view.light_angle_deg
    if view.side == BTDF:
        if a > 0:
            return (f"a slab transmits around the straight-through direction v = -l, which this camera sees only "
                    f"with the light straight behind the sphere (0°); at {a:g}° a transmitted peak narrower than "
                    f"the slice grid (smooth interfaces) reaches no pixel")
        return "no recorded light reaches the camera"
    return ("a reflected peak narrower than the slice grid (smooth interfaces) is a point highlight at the "
            "mirror point (normal halfway between light and view), marked with a ring")


def view_text(view: SphereView) -> str:
    """The view in words, for titles."""
    if view.side == BTDF:
        return f"BTDF, sphere backlit at {view.light_angle_deg:g}° from the line of sight"
    return f"light at {view.light_angle_deg:g}° from the view"


def comparison_figure(spheres: SphereSet, *, splits: bool = True, caption: bool = True, title: str | None = None):
    """The figure: the reference and every model beside it (one exposure), labelled with the model
    name and its image RMSE; with ``splits``, a second row of split spheres (left half reference,
    right half model). ``caption``: the reference's description, the exposure rule and the hatching."""
    inside = spheres.view.inside
    panels = {n: fill(spheres.display(n), inside) for n in spheres.images}
    note = spheres.reference_note
    if note is not None and spheres.view.mirror_point is not None:
        panels[REFERENCE] = ring(panels[REFERENCE], *spheres.view.mirror_point)
    top = [(REFERENCE if note is None else f"{REFERENCE}\n(cannot be shown)", panels[REFERENCE])]
    top += [(f"{n}\n" + (f"RMSE {spheres.rmse(n):.3g}" if np.isfinite(spheres.rmse(n)) else "no RMSE"), panels[n])
            for n in spheres.models]
    rows = [top]
    if splits and spheres.models:
        rows.append([("", None)] + [(f"◧ reference | {n}", split(panels[REFERENCE], panels[n]))
                                     for n in spheres.models])
    title = title or f"{spheres.reference.stack.name}: {view_text(spheres.view)}"
    lines = [] if note is None else [
        f"The reference cannot be shown: {note}." + (" The models are exposed on their own pixels by the same "
                                                     "rule, without an image RMSE." if spheres.models else "")]
    if caption:
        lines += [f"Reference: {spheres.reference.description}.",
                  f"{EXPOSURE_RULE}; image RMSE in those linear display units (white = 1). "
                  f"Hatched: no value (light outside the recorded incident range, or only masked cells)."]
        if spheres.skipped:
            lines.append("Not rendered: " + "; ".join(f"{n} ({r})" for n, r in spheres.skipped.items()) + ".")
        if spheres.failed:
            lines.append("Failed: " + "; ".join(f"{n} ({r})" for n, r in spheres.failed.items()) + ".")
    text = "\n".join(lines) or None
    return figure(rows, title, text)


def render_file(path: str | Path, out: str | Path, models: Sequence[str] | None = None,
                light_angle_deg: float = 30.0, size: int = 512) -> SphereSet:
    """``gonio render``: the reference of ``path`` (a slices or tabulated file) and ``models``
    (names, ``["all"]`` or None for none) on a sphere, written as a PNG to ``out``."""
    names = model_names(models)
    reference = open_reference(path)
    view = SphereView(size, light_angle_deg, reference.side)
    spheres = render_spheres(reference, names, view)
    write_png(out, comparison_figure(spheres))
    return spheres
