"""The report's lit spheres (``docs/report.md``, spheres; ``docs/render.md``): per material the
reference and every rendered model at :data:`SPHERE_ANGLES_DEG`, and Bati 2019 figure 1 (the frosted
metal alpha0 = 0.05, alpha1 = 0.2, yellow-tinted tau, eta1 = 1.2: reference, WW09, Elek, Belcour
forward and symmetric).

The linear sphere images are cached beside the material's evaluation (``cache/<material>.spheres.h5``)
under a key made of the evaluation key (reference file, model code -- :mod:`models.render`
included --, models), the light angle, the size and :data:`SPHERES_VERSION`; the PNGs are redrawn
when that key or the report code changes (``figures/<material>/spheres.json``).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Sequence

import h5py
import numpy as np

from goniometer.files import slices as store
from goniometer.run.results import SimulationResult
from models import registry
from models.base import ModelError
from models.evaluation import group_name
from models.render import (RenderError, SphereSet, SphereView, comparison_figure, render_views,
                           slices_reference, view_text)
from models.render.reference import Reference
from models.report.evaluation import read_reference
from models.report.files import OnceWriter, material_dir, read_json, write_json
from models.report.panels import save_figure
from models.report.results import MaterialResult, ReportMaterial

#: light angles (degrees from the view direction) of every material's spheres, and their size
SPHERE_ANGLES_DEG = (30.0, 65.0)
SPHERE_PX = 96
#: Bati 2019 figure 1: its models (in the paper's order), light angle and sphere size
FIGURE1_MODELS = ("ww09", "elek10", "belcour-fwd", "belcour-sym")
FIGURE1_ANGLE_DEG = 30.0
FIGURE1_PX = 200
FIGURE1_FILE = "figures/figure1.png"
SPHERES_FORMAT = "goniometer.report-spheres"
#: bump when the cached images change in a way the model code key does not show
SPHERES_VERSION = 1


def spheres_cache_path(out: Path, name: str) -> Path:
    """The sphere cache of material ``name`` in report ``out`` (beside its evaluation cache)."""
    base = out / "cache" / material_dir(name)
    return base.with_name(base.name + ".spheres.h5")


def _key(eval_key: str, angle: float, size: int, names: Sequence[str]) -> str:
    doc = {"v": SPHERES_VERSION, "evaluation": eval_key, "angle": angle, "size": size, "models": list(names)}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:20]


def _rendered_models(res: MaterialResult) -> list[str]:
    """The evaluated models that can be rendered (the analytic ones and adapter specs; fitted models
    need their fit)."""
    analytic = registry.all_models()
    return [n for n in res.evaluation["models"] if n in analytic or registry.is_spec(n)]


def _load(path: Path, tag: str, key: str) -> tuple[dict[str, np.ndarray], dict[str, str], str, dict[str, str]] | None:
    try:
        with h5py.File(path, "r") as f:
            if tag not in f or f[tag].attrs.get("key") != key:
                return None
            g = f[tag]
            images = {n: g[group_name(n)][()].astype(np.float64) for n in json.loads(g.attrs["order"])}
            failed = json.loads(g.attrs["failed"]) if "failed" in g.attrs else {}
            return images, json.loads(g.attrs["skipped"]), str(g.attrs["description"]), failed
    except (OSError, KeyError, ValueError):
        return None


def _save(path: Path, tag: str, key: str, spheres: SphereSet) -> None:
    """Add (or replace) the view ``tag`` in the cache file, keeping the other views."""
    path.parent.mkdir(parents=True, exist_ok=True)
    keep: dict[str, tuple[dict, dict]] = {}
    try:
        with h5py.File(path, "r") as f:
            for t in f:
                if t != tag:
                    keep[t] = ({n: f[t][n][()] for n in f[t]}, dict(f[t].attrs))
    except (OSError, KeyError, ValueError):
        keep = {}
    with store.atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = SPHERES_FORMAT
            once = OnceWriter(f)
            for t, (data, attrs) in keep.items():
                g = f.create_group(t)
                g.attrs.update(attrs)
                for n, a in data.items():
                    once.put(f"{t}/{n}", a, per_incident=False)
            g = f.create_group(tag)
            g.attrs.update({"key": key, "order": json.dumps(list(spheres.images)),
                            "skipped": json.dumps(spheres.skipped), "failed": json.dumps(spheres.failed),
                            "description": spheres.reference.description})
            for n, img in spheres.images.items():
                once.put(f"{tag}/{group_name(n)}", img.astype(np.float32), per_incident=False)


class _Lazy:
    """The material's reference, read once and only when a cached view is missing."""

    def __init__(self, mat: ReportMaterial, ref: SimulationResult | None) -> None:
        self.mat, self.ref, self._reference = mat, ref, None

    def reference(self) -> Reference:
        if self._reference is None:
            if self.ref is None:
                self.ref = read_reference(self.mat.path)
            self._reference = slices_reference(self.ref, str(self.mat.path))
        return self._reference


def sphere_sets(res: MaterialResult, lazy: _Lazy, out: Path, specs: Sequence[tuple[str, float, int]],
                names: Sequence[str]) -> tuple[list[SphereSet], bool]:
    """The views ``specs`` (tag, light angle, size) of a material, from the cache or rendered
    together (:func:`models.render.render_views`); True if rendered."""
    path = spheres_cache_path(out, res.material.name)
    keys = [_key(res.key, angle, size, names) for _, angle, size in specs]
    hits = [_load(path, tag, key) for (tag, _, _), key in zip(specs, keys)]
    if all(h is not None for h in hits):
        stack = store.describe(res.material.path)[0] if lazy.ref is None else lazy.ref.stack
        side = "btdf" if stack.transmits else "brdf"
        out_sets = []
        for (tag, angle, size), (images, skipped, description, failed) in zip(specs, hits):
            reference = Reference(stack, side, None, description)   # the images are cached: no BSDF needed
            out_sets.append(SphereSet(SphereView(size, angle, side), reference, images, skipped, failed))
        return out_sets, False
    reference = lazy.reference()
    sets = render_views(reference, list(names), [SphereView(size, angle, reference.side) for _, angle, size in specs])
    for (tag, _, _), key, spheres in zip(specs, keys, sets):
        _save(path, tag, key, spheres)
        # drawn from the images as the cache keeps them (float32), as a rerun draws them
        spheres.images = {n: img.astype(np.float32).astype(np.float64) for n, img in spheres.images.items()}
    return sets, True


def _sphere_file(angle: float) -> str:
    return f"sphere_{angle:g}.png"


def material_spheres(res: MaterialResult, ref: SimulationResult | None, out: Path, report_key: str) -> dict:
    """The spheres of one material at :data:`SPHERE_ANGLES_DEG`: one PNG per angle (reference and
    the rendered models beside it, one exposure), cached. Returns the HTML entries
    ``{"spheres": [{"angle", "src", "rmse"}], "spheres_note": str}`` (a note says why there are none,
    or which models are not rendered) and ``"not_drawn"``: ``[{"figure", "reason"}]`` for every
    sphere whose reference cannot be shown (black or without a value there: its PNG says why and
    marks where a peak too narrow for the grid lies, ``docs/render.md`` 6) or that could not be
    rendered at all."""
    names = _rendered_models(res)
    notes = [f"{n}: fitted models are not rendered" for n in res.evaluation["models"] if n not in names]
    lazy = _Lazy(res.material, ref)
    rel = Path("figures") / material_dir(res.material.name)
    entries = []
    keys = [_key(res.key, angle, SPHERE_PX, names) for angle in SPHERE_ANGLES_DEG]
    try:
        sets, _ = sphere_sets(res, lazy, out, [(f"a{a:g}", a, SPHERE_PX) for a in SPHERE_ANGLES_DEG], names)
    except (RenderError, ModelError, store.StoreError) as e:
        return {"spheres": [], "spheres_note": f"no spheres: {e}",
                "not_drawn": [{"figure": _sphere_file(a), "reason": f"no spheres: {e}"} for a in SPHERE_ANGLES_DEG]}
    drawn_sets = dict(zip(SPHERE_ANGLES_DEG, sets))
    stamp_path = out / rel / "spheres.json"
    fkey = hashlib.sha256(json.dumps([keys, report_key]).encode()).hexdigest()[:20]
    stamp = read_json(stamp_path)
    not_drawn = [{"figure": _sphere_file(angle), "reason": spheres.reference_note}
                 for angle, spheres in drawn_sets.items() if spheres.reference_note is not None]
    for angle, spheres in drawn_sets.items():
        src = f"{rel.as_posix()}/{_sphere_file(angle)}"
        entries.append({"angle": angle, "src": src, "rmse": {n: spheres.rmse(n) for n in spheres.models},
                        "reference": spheres.reference.description})
    if not (stamp and stamp.get("key") == fkey and all((out / e["src"]).is_file() for e in entries)):
        for angle, spheres in drawn_sets.items():
            fig = comparison_figure(spheres, splits=False, caption=False,
                                    title=f"{view_text(spheres.view)}")
            save_figure(fig, out / rel / _sphere_file(angle))
        write_json(stamp_path, {"key": fkey})
    skipped = drawn_sets[SPHERE_ANGLES_DEG[0]].skipped if drawn_sets else {}
    notes += [f"{n}: {r}" for n, r in skipped.items()]
    failed = drawn_sets[SPHERE_ANGLES_DEG[0]].failed if drawn_sets else {}
    notes += [f"{n} failed: {r}" for n, r in failed.items()]
    not_drawn += [{"figure": "spheres", "reason": f"{n} not rendered: it failed: {r}"} for n, r in failed.items()]
    for e in entries:
        e["rmse"] = {n: (v if np.isfinite(v) else None) for n, v in e["rmse"].items()}
    return {"spheres": entries, "spheres_note": "; ".join(notes), "not_drawn": not_drawn}


def is_figure1(mat: ReportMaterial) -> bool:
    """Whether ``mat`` is the material of Bati 2019 figure 1: a metal with alpha0 = 0.05, alpha1 = 0.2,
    eta1 = 1.2 and a yellow-tinted (chromatic, blue absorbed most) coat."""
    p = mat.params
    eta1 = p.get("eta1")
    eta1 = eta1[0] if isinstance(eta1, (list, tuple)) else eta1
    tau = p.get("tau")
    return (mat.category == "metal" and p.get("alpha0") == 0.05 and p.get("alpha1") == 0.2 and eta1 == 1.2
            and isinstance(tau, (list, tuple)) and len(tau) == 3 and tau[2] > tau[1] > tau[0])


def figure1(results: Sequence[MaterialResult], out: Path, report_key: str) -> dict | None:
    """Bati 2019 figure 1 from the first material :func:`is_figure1` accepts: the reference, then
    WW09, Elek, Belcour forward and symmetric beside it and split with it (left half reference),
    light at :data:`FIGURE1_ANGLE_DEG`. Returns ``{"src", "material", "models", "missing",
    "rmse", "caption", "not_drawn"}`` (``not_drawn``: ``[{"figure", "reason"}]``, empty when the
    reference is shown) or None if the results hold no such material."""
    res = next((r for r in results if is_figure1(r.material)), None)
    if res is None:
        return None
    evaluated = set(_rendered_models(res))
    names = [n for n in FIGURE1_MODELS if n in evaluated]
    missing = [n for n in FIGURE1_MODELS if n not in evaluated]
    try:
        (spheres,), rendered = sphere_sets(res, _Lazy(res.material, None), out,
                                           [("figure1", FIGURE1_ANGLE_DEG, FIGURE1_PX)], names)
    except (RenderError, ModelError, store.StoreError) as e:
        return {"src": None, "material": res.material.name, "models": names, "missing": missing,
                "rmse": {}, "caption": f"figure 1 could not be rendered: {e}",
                "not_drawn": [{"figure": FIGURE1_FILE, "reason": f"figure 1 could not be rendered: {e}"}]}
    fkey = hashlib.sha256(json.dumps([_key(res.key, FIGURE1_ANGLE_DEG, FIGURE1_PX, names), report_key])
                          .encode()).hexdigest()[:20]
    stamp = read_json(out / "figures" / "figure1.json")
    if rendered or not (stamp and stamp.get("key") == fkey and (out / FIGURE1_FILE).is_file()):
        title = (f"Bati 2019 figure 1: {res.material.name} (α0 = 0.05, α1 = 0.2, yellow-tinted τ, η1 = 1.2), "
                 f"{view_text(spheres.view)}")
        save_figure(comparison_figure(spheres, splits=True, caption=True, title=title), out / FIGURE1_FILE)
        write_json(out / "figures" / "figure1.json", {"key": fkey})
    rmse = {n: spheres.rmse(n) for n in spheres.models}
    return {"src": FIGURE1_FILE, "material": res.material.name, "models": names, "missing": missing,
            "rmse": {n: (v if np.isfinite(v) else None) for n, v in rmse.items()},
            "caption": spheres.reference.description,
            "not_drawn": [] if spheres.reference_note is None else
            [{"figure": FIGURE1_FILE, "reason": spheres.reference_note}]}
