"""A material's evaluation by the models and its cache in the report directory.

The evaluation of a material is keyed by the content hash of its reference file, the hash of the
model code (:func:`model_code_key`: the project's and the installed model plugins'), the number of
sub-cells, the requested models (with the code of adapter specs among them) and the isotropization; the figures are keyed by that key and :func:`report_code_key`. The cache files and
the rules are described in ``docs/report.md`` (caching).
"""

from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path
from typing import Iterable, Sequence

import h5py
import numpy as np

from goniometer.files import slices as store
from goniometer.cache import package_key
from goniometer.run.results import SimulationResult
from models import registry
from models._jit import models_key
from models.base import ModelError
from models.compare.errors import NoCellsError, require_cells
from models.evaluation import comparison_side, evaluate, group_name
from models.report.files import OnceWriter, material_dir, read_json, write_json
from models.report.results import MaterialResult, ReportError, ReportMaterial

CACHE_FORMAT = "goniometer.report-cache"
CACHE_VERSION = 1
#: bump when the figures change in a way the module source hash would not capture
FIGURE_VERSION = 2
#: precision of the model slices kept in the cache (for figures only)
SLICE_CACHE_MANTISSA_BITS = 11


def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def model_code_key() -> str:
    """Hash of the sources that determine the registered models' values and errors: the models' key
    (:func:`models._jit.models_key`: ``goniometer`` and ``models`` without their application),
    followed, when model plugins are installed, by :func:`models.registry.code_key` of them (each
    plugin's distribution, version and module sources), so that an updated plugin is evaluated
    again. Adapter specs enter each evaluation's key instead (:func:`_evaluation_key`)."""
    extra = registry.code_key(None)
    return models_key() + (f"+{extra}" if extra else "")


def report_code_key() -> str:
    """Hash of the figures' code (the report package; the HTML assets do not change figures, and
    the page is rewritten on every run anyway)."""
    return package_key(("models.report",)) + f"-{FIGURE_VERSION}"


def _reference_digest(path: Path, previous: dict | None) -> dict:
    st = path.stat()
    if previous and previous.get("size") == st.st_size and previous.get("mtime_ns") == st.st_mtime_ns:
        return previous
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns, "sha256": _sha256_file(path)}


def _evaluation_key(digest: str, code: str, subcells: int, models: Sequence[str] | None,
                    isotropize: str | None = None) -> str:
    doc = {"v": CACHE_VERSION, "reference": digest, "code": code, "subcells": subcells,
           "models": sorted(models) if models is not None else "all", "isotropize": isotropize}
    specs = [m for m in models or () if registry.is_spec(m)]
    if specs:   # the adapters' modules and files (absent otherwise: the other keys stay as they were)
        doc["adapters"] = registry.code_key(specs)
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:20]


def cache_paths(out: Path, name: str) -> tuple[Path, Path]:
    """The cache files of material ``name`` in report ``out``: ``(entry.json, slices.h5)``."""
    base = out / "cache" / material_dir(name)
    return base.with_name(base.name + ".json"), base.with_name(base.name + ".h5")


def judged_side(reference: SimulationResult, where: str) -> str:
    """The side ``reference`` is judged on ("brdf" or "btdf"); ReportError if the file lacks it."""
    side = comparison_side(reference.stack)
    if (reference.brdf if side == "brdf" else reference.btdf) is None:
        raise ReportError(f"{where}: the file has no {side.upper()} slices, which a {reference.stack.base}-base "
                          f"stack is judged on")
    return side


def run_evaluation(reference: SimulationResult, models: Sequence[str] | None, subcells: int,
                   isotropize: str | None = None, seconds: dict[str, float] | None = None
                   ) -> tuple[dict, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Evaluate ``models`` (None: all of the registry) on ``reference``, one model at a time.
    Returns the ``gonio evaluate --json`` object (with ``failed``: model -> message for the models
    that failed, :class:`models.base.ModelFailure`, which :func:`models.evaluation.evaluate`
    records, and ``cells``, ``cells_total``: the support of every error) and model -> (top,
    internal). A reference without a valid cell on its side judges no model: each model is failed
    with the reason (``docs/report.md``), and the other materials stand. ``seconds``, if given,
    receives each evaluated model's time (wall clock).
    """
    stack = reference.stack
    side = judged_side(reference, stack.name)
    doc = {"material": stack.name, "category": stack.category, "side": side, "models": {}, "skipped": {},
           "failed": {}}
    if models is None:   # every model that applies, as a default evaluate chooses them
        names = []
        for name, model in registry.all_models().items():
            if model.on_request:
                doc["skipped"][name] = model.on_request_note()
            else:
                names.append(name)
    else:
        names = list(models)
    try:
        cov = require_cells(reference, side)
    except NoCellsError as e:
        doc["cells"], doc["cells_total"] = 0, e.coverage.cells_total if e.coverage is not None else 0
        doc["failed"] = {name: str(e) for name in names}
        return doc, {}
    doc["cells"], doc["cells_total"] = cov.cells, cov.cells_total
    slices: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name in names:
        t0 = time.perf_counter()
        try:
            ev = evaluate(reference, [name], s=subcells, isotropize=isotropize)
        except ModelError as e:
            msg = str(e)
            doc["skipped"][name] = msg[len(name) + 2:] if msg.startswith(f"{name}: ") else msg
            continue
        if name in ev.failed:
            doc["failed"][name] = ev.failed[name]
            continue
        doc["models"][name] = ev.errors[name]
        for key in ("fits", "approximations"):
            if name in getattr(ev, key):
                doc.setdefault(key, {})[name] = getattr(ev, key)[name]
        ms = ev.slices[name]
        slices[name] = (ms.top, ms.internal)
        if seconds is not None:
            seconds[name] = time.perf_counter() - t0
    return doc, slices


def cached_evaluations(out: Path) -> int:
    """How many materials' evaluations the cache of report ``out`` holds (its ``cache/**/<material>.json``
    entries): what an interrupted report leaves, and a rerun resumes from."""
    root = Path(out) / "cache"
    return sum(1 for p in root.rglob("*.json") if p.is_file()) if root.is_dir() else 0


def round_mantissa(a: np.ndarray, bits: int = SLICE_CACHE_MANTISSA_BITS) -> np.ndarray:
    """``a`` as float32 rounded to ``bits`` explicit mantissa bits (relative error <= 2**-(bits+1));
    the dropped bits are zero, which lets gzip + shuffle compress the slices about 2x better."""
    u = np.ascontiguousarray(a, dtype=np.float32).view(np.uint32)
    drop = 23 - bits
    u = (u + np.uint32(1 << (drop - 1))) & np.uint32((0xFFFFFFFF << drop) & 0xFFFFFFFF)
    return u.view(np.float32)


def _save_cache(json_path: Path, h5_path: Path, entry: dict, slices: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    """The integrated model slices (for figures only: float32 rounded by :func:`round_mantissa`,
    each distinct array once, chunked per incident direction, :class:`models.report.files.OnceWriter`;
    the errors are computed at full precision and kept in the JSON) and the JSON entry."""
    h5_path.parent.mkdir(parents=True, exist_ok=True)
    with store.atomic_path(h5_path) as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = CACHE_FORMAT
            f.attrs["key"] = entry["key"]
            f.attrs["precision"] = f"float32 rounded to {SLICE_CACHE_MANTISSA_BITS} mantissa bits"
            once = OnceWriter(f)
            for name, (top, internal) in slices.items():
                g = f.create_group(group_name(name))
                for part, arr in (("top", top), ("internal", internal)):
                    once.put(f"{g.name}/{part}", round_mantissa(arr))
    write_json(json_path, entry)  # written last: it vouches for the slices file by its key


def figure_slices(slices: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The slices the figures are drawn from: as the cache keeps them (:func:`round_mantissa`, read
    back as float64), so that figures drawn from a fresh evaluation and from the cache are the same."""
    return {n: (round_mantissa(t).astype(np.float64), round_mantissa(i).astype(np.float64))
            for n, (t, i) in slices.items()}


def load_slices(h5_path: Path, key: str, names: Iterable[str]) -> dict[str, tuple[np.ndarray, np.ndarray]] | None:
    """The cached (top, internal) slices of ``names`` as float64, or None if the file is unreadable
    or was written for another key."""
    try:
        with h5py.File(h5_path, "r") as f:
            if f.attrs.get("key") != key:
                return None
            return {n: (f[f"{group_name(n)}/top"][()].astype(np.float64),
                        f[f"{group_name(n)}/internal"][()].astype(np.float64))
                    for n in names}
    except (OSError, KeyError, ValueError):
        return None


def _slices_key(path: Path) -> str | None:
    try:
        with h5py.File(path, "r") as f:
            k = f.attrs.get("key")
            return k.decode() if isinstance(k, bytes) else (str(k) if k is not None else None)
    except OSError:
        return None


def read_reference(path: Path) -> SimulationResult:
    """The simulated file ``path``; ReportError (naming the file) if it cannot be read."""
    try:
        return store.read(path)
    except store.StoreError as e:
        raise ReportError(str(e) if str(path) in str(e) else f"{path}: {e}") from None


def evaluate_material(mat: ReportMaterial, out: Path, models: Sequence[str] | None, subcells: int, code: str,
                      isotropize: str | None = None) -> tuple[MaterialResult, SimulationResult | None]:
    """Cached or fresh evaluation of one material (and the reference if it had to be read)."""
    json_path, h5_path = cache_paths(out, mat.name)
    cached = read_json(json_path)
    ok_cache = cached is not None and cached.get("format") == CACHE_FORMAT and cached.get("version") == CACHE_VERSION
    digest = _reference_digest(mat.path, cached.get("reference") if ok_cache else None)
    key = _evaluation_key(digest["sha256"], code, subcells, models, isotropize)
    if ok_cache and cached.get("key") == key and _slices_key(h5_path) == key:
        return MaterialResult(mat, cached["evaluation"], key, None, True), None
    ref = read_reference(mat.path)
    t0 = time.perf_counter()
    seconds: dict[str, float] = {}
    evaluation, slices = run_evaluation(ref, models, subcells, isotropize, seconds)
    entry = {"format": CACHE_FORMAT, "version": CACHE_VERSION, "key": key, "reference": digest,
             "reference_path": str(mat.path), "evaluation": evaluation, "subcells": subcells,
             "elapsed_s": time.perf_counter() - t0, "model_elapsed_s": seconds}
    _save_cache(json_path, h5_path, entry, slices)
    return MaterialResult(mat, evaluation, key, figure_slices(slices), False), ref


def warm_up_models(materials: Sequence[ReportMaterial], models: Sequence[str] | None, subcells: int,
                   isotropize: str | None = None) -> None:
    """Compile, or load from numba's cache, what evaluating ``materials`` calls, here, before worker
    processes start (:mod:`models.workers`: two workers compiling one function at once would both
    write it to the cache): for the first material of each (category, parametrization), the grid's
    sub-cells, masks, solid angles and top-view pixels on a tiny grid of its kind, and every model
    that applies evaluated at a few directions. Whatever fails here is left to the evaluation, which
    reports it (a model's failure is one line of the report, never the warm-up's)."""
    from goniometer.grids.slice_grid import SliceGrid, light_direction
    from models.evaluation import isotropized
    from models.report.geometry import pixel_map
    seen = set()
    for mat in materials:
        if (mat.category, mat.parametrization) in seen:
            continue
        seen.add((mat.category, mat.parametrization))
        try:
            stack, _ = store.describe(mat.path)
            side = comparison_side(stack)
            grid = SliceGrid(mat.parametrization, 2, 4, "reflection" if side == "brdf" else "transmission")
            light = light_direction(30.0, 0.0)
            v, _ = grid.subcells(light, min(subcells, 2))
            mask = grid.mask(light, min(subcells, 2))
            grid.proj_solid_angle(light)
            pixel_map(grid, light, mask, 4)
        except Exception:  # noqa: BLE001 -- the evaluation reports what is wrong with the file
            continue
        names = models if models is not None else [n for n, m in registry.all_models().items() if not m.on_request]
        try:
            available = registry.models_for(list(names))
        except ModelError:   # a bad adapter spec: the evaluation says so
            continue
        for name, model in available.items():
            if name not in names:
                continue
            try:
                model_stack = stack
                if isotropize and not model.anisotropic:
                    model_stack = isotropized(stack, isotropize)
                if side in model.sides and model.reason(model_stack) is None:
                    model.evaluate(model_stack, light, v.reshape(-1, 3)[:8], side)
            except Exception:  # noqa: BLE001 -- a model's failure is the evaluation's to report
                continue
