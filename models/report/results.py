"""The materials of a results directory of ``gonio database simulate`` as the report sees them:
:func:`open_results` reads the manifest and finds the finished files; :class:`ReportMaterial`
describes one, :class:`MaterialResult` holds its evaluation; the material parameters and their
display text."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from goniometer.files import slices as store
from goniometer.database import (MANIFEST, RESULTS_FORMAT, Database, DatabaseError, load_database,
                                 material_path)
from goniometer.stack import Interface, Lambertian, Medium, Stack

#: parameters reported per material, in display order, with their labels
PARAM_KEYS = ("alpha0", "alpha1", "tau", "rho", "eta1")
PARAM_LABELS = {"alpha0": "α0", "alpha1": "α1", "tau": "τ", "rho": "ρ", "eta1": "η1",
                "paper_name": "name", "name": "material"}


class ReportError(ValueError):
    """Bad input for a report (not a results directory, no materials, unreadable file, unknown
    model); the message names the file or the problem."""


@dataclass(frozen=True)
class ReportMaterial:
    """A finished material of the results directory."""

    name: str
    category: str
    paper_name: str
    params: dict[str, Any]
    parametrization: str
    path: Path
    rays: int
    resolution: tuple[int, int]


@dataclass
class MaterialResult:
    """Evaluation of one material: ``evaluation`` is the ``gonio evaluate --json`` object (plus a
    ``failed`` mapping for models that raised); ``slices`` maps a model to (top, internal);
    ``not_drawn``: ``[{"material", "figure", "reason"}]``, the figures of this material that could
    not be drawn or whose reference cannot be shown (``errors.json``, ``docs/report.md``)."""

    material: ReportMaterial
    evaluation: dict
    key: str
    slices: dict[str, tuple[np.ndarray, np.ndarray]] | None = None
    from_cache: bool = False
    figures: dict = field(default_factory=dict)
    not_drawn: list[dict] = field(default_factory=list)

    def missing_figure(self, figure: str, reason: str) -> None:
        """Record that ``figure`` (a file name or a figure's name) of this material was not drawn, or
        is drawn without its reference, and why."""
        self.not_drawn.append({"material": self.material.name, "figure": figure, "reason": reason})


def format_value(v: Any) -> str:
    """Display text of a parameter value: floats with ``:g``, lists as ``(a, b, c)``."""
    if isinstance(v, (list, tuple)):
        return "(" + ", ".join(format_value(x) for x in v) + ")"
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def param_text(params: dict, key: str) -> str | None:
    """Display text of a parameter: the symbol name for tau/rho when the definition gave one."""
    if key not in params:
        return None
    name = params.get(f"{key}_name")
    return str(name) if name is not None else format_value(params[key])


def material_sort_key(m: ReportMaterial) -> tuple:
    """Display order of materials within a category: alpha0, paper name, alpha1, eta1, name."""
    p = m.params
    return (p.get("alpha0", 0.0), m.paper_name, p.get("alpha1", 0.0), str(p.get("eta1", "")), m.name)


def open_results(results_dir: str | Path, definition: str | Path | None = None,
                 exclude: Path | None = None) -> tuple[dict, list[ReportMaterial], list[str], list[str]]:
    """Read a results directory: ``(manifest, materials, missing, warnings)``.

    Materials come from the database definition named in the manifest (found relative to the
    working directory or to the results directory and its parents), or ``definition`` if given;
    if it cannot be found or no longer matches the manifest's fingerprint, from the ``.h5``
    files themselves (parameters derived from the stacks; a warning says so). ``missing`` lists
    materials of the definition without a finished file. Raises :class:`ReportError`.
    """
    rd = Path(results_dir)
    if rd.exists() and not rd.is_dir():
        raise ReportError(f"{rd}: is a file, not a results directory of `gonio database simulate`")
    if not rd.is_dir():
        raise ReportError(f"{rd}: no such directory")
    mf = rd / MANIFEST
    if not mf.is_file():
        raise ReportError(f"{rd}: not a results directory of `gonio database simulate` (no {MANIFEST})")
    try:
        manifest = json.loads(mf.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ReportError(f"{mf}: unreadable manifest ({e})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != RESULTS_FORMAT:
        raise ReportError(f"{mf}: not a manifest of `gonio database simulate` (format is not {RESULTS_FORMAT!r})")
    warnings: list[str] = []
    db = _definition(rd, manifest, definition, warnings)
    missing: list[str] = []
    if db is not None:
        found = []
        for m in db.materials:
            p = material_path(rd, m)
            if p.is_file():
                found.append((m.name, m.category, m.paper_name, dict(m.params), m.parametrization, p, m.stack))
            else:
                missing.append(m.name)
    else:
        found = _scan_files(rd, exclude)
    materials = [_check_file(*entry) for entry in found]
    if not materials:
        raise ReportError(f"{rd}: no finished materials (no <category>/<material>.h5 files"
                          f"{'; ' + str(len(missing)) + ' material(s) of the definition are missing' if missing else ''})")
    return manifest, materials, missing, warnings


def _definition(rd: Path, manifest: dict, explicit: str | Path | None, warnings: list[str]) -> Database | None:
    if explicit is not None:
        try:
            db = load_database(explicit)
        except DatabaseError as e:
            raise ReportError(str(e)) from None
        if db.fingerprint() != manifest.get("fingerprint"):
            raise ReportError(f"{explicit}: is not the definition {rd} was simulated from (fingerprint "
                              f"{db.fingerprint()} != {manifest.get('fingerprint')})")
        return db
    named = manifest.get("definition")
    if not named:
        warnings.append(f"{rd / MANIFEST}: names no definition; parameters derived from the files")
        return None
    p = Path(named)
    candidates = [p] if p.is_absolute() else [Path.cwd() / p, rd / p] + [a / p for a in rd.resolve().parents]
    path = next((c for c in candidates if c.is_file()), None)
    if path is None:
        warnings.append(f"definition {named} not found (from {Path.cwd()} or {rd}); parameters and paper names "
                        f"derived from the files")
        return None
    try:
        db = load_database(path)
    except DatabaseError as e:
        warnings.append(f"{e}; parameters derived from the files")
        return None
    if db.fingerprint() != manifest.get("fingerprint"):
        warnings.append(f"{path} changed since {rd} was simulated (fingerprint differs); parameters derived "
                        f"from the files")
        return None
    return db


def _scan_files(rd: Path, exclude: Path | None) -> list[tuple]:
    out = []
    ex = exclude.resolve() if exclude is not None else None
    for p in sorted(rd.rglob("*.h5")):
        rel = p.relative_to(rd)
        if any(part.startswith(".") for part in rel.parts):
            continue
        if ex is not None and (p.resolve() == ex or ex in p.resolve().parents):
            continue
        stack = _describe(p)[0]
        base = stack.name.split("/")[-1]
        out.append((stack.name, stack.category, base.split("-")[0], params_from_stack(stack), None, p, stack))
    return out


def _describe(p: Path):
    try:
        return store.describe(p)
    except store.StoreError as e:
        raise ReportError(str(e) if str(p) in str(e) else f"{p}: {e}") from None


def _check_file(name: str, category: str, paper_name: str, params: dict, parametrization: str | None,
                path: Path, stack: Stack) -> ReportMaterial:
    have, settings = _describe(path)
    if settings.spectral:
        raise ReportError(f"{path}: a spectral run ({settings.wavelength_bins} wavelength bins); the report's "
                          f"figures and tables are of RGB slices: report an RGB database (without spectral = true "
                          f"in [simulation]), or judge one file with `gonio evaluate` (docs/spectral.md)")
    if have.to_json() != stack.to_json():
        raise ReportError(f"{path}: holds another stack than the definition's {name}; rerun `gonio database "
                          f"simulate --resimulate-corrupted`")
    # the definition's parameters, completed by those read off the stack (literal layer values)
    return ReportMaterial(name=name, category=category, paper_name=paper_name,
                          params={**params_from_stack(stack), **params},
                          parametrization=parametrization or settings.parametrization, path=path,
                          rays=settings.rays, resolution=tuple(settings.resolution))


def params_from_stack(stack: Stack) -> dict[str, Any]:
    """alpha0, tau, rho, alpha1, eta1 read off a [interface, medium, base] stack (where they apply)."""
    layers = stack.layers
    out: dict[str, Any] = {}
    if layers and isinstance(layers[0], Interface):
        out["alpha0"] = layers[0].roughness
    media = [x for x in layers if isinstance(x, Medium)]
    if media:
        out["tau"] = list(media[0].optical_depth)
    base = layers[-1]
    if isinstance(base, Lambertian):
        out["rho"] = list(base.albedo)
    elif isinstance(base, Interface) and len(stack.interfaces) >= 2:
        out["alpha1"] = base.roughness
        if base.is_conductor:
            out["eta1"] = base.ior[0] if len(set(base.ior)) == 1 else list(base.ior)
    return out
