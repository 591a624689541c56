"""Reports over a database results directory: error tables, figure-4-style plots, per-material
figures, a static HTML browser and the reproduction checks of Bati et al. 2019, section 4.2.

``build_report(results_dir, out_dir)`` evaluates every finished material of a results directory
of ``gonio database simulate`` with the models of :mod:`models.registry` (whatever
:func:`models.compare.evaluate.evaluate` applies to it) and writes::

    <out>/index.html                  static browser: works from file://, no server, no network;
                                      its data is embedded, images are referenced relatively
    <out>/errors.json                 a list, one record per (material, evaluated model)
    <out>/reproduction.json, .md      each finding of section 4.2 next to what our errors show
    <out>/tables/<category>.csv, .md  error tables per category
    <out>/figures/errors_<category>.png, errors_overview.png   figure-4-style plots
    <out>/figures/<category>/<material>/
        plane_m<k>.png                incident-plane curves (reference and models), incident k
        top_m<k>_<model>.png          top views of the slice: RGB, luminance isovalues, difference
                                      (``reference``: RGB, isovalues, 2-sigma noise)
        orders_m<k>.png               bounce-order decomposition of the reference (figure 13)
        energy.png                    energy per bounce order against incidence
        stamp.json                    key of the inputs the figures were drawn from
    <out>/cache/<category>/<material>.json, .h5    evaluation cache (errors; integrated slices)

Caching: a material's evaluation is keyed by the content hash of its reference file (re-hashed
only when its size or mtime changes), a hash of the model code (every source file of the
``goniometer`` and ``models`` packages except this reporting module), the number of sub-cells
and the requested models. Its figures are keyed by that key, this module's source and the figure
options. A rerun only redoes what changed. Every output file is written atomically (temporary
file + rename).

Figures use the paper's remap ``g(f) = log(1 + sqrt(f))``. Top views are orthographic views of
the outgoing hemisphere in ``v`` (pixel = direction ``(v_x, v_y)``, seen from above; for a BTDF
the lower hemisphere seen through the surface); each pixel shows the cell its direction falls
in, so half-vector slices are drawn with their true cell geometry. The incident-plane curves use
the cells next to the plane ``phi = phi_l, phi_l + 180`` (mean of the two adjacent columns),
placed at the direction of the cell centre; the horizontal axis is the signed elevation of
``v``, positive on the side of the mirror (BRDF) or straight-through (BTDF) direction.
"""

from __future__ import annotations

import csv
import hashlib
import html
import io
import json
import math
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import h5py
import numpy as np

from goniometer import atomic, store
from goniometer.database import (MANIFEST, RESULTS_FORMAT, Database, DatabaseError, load_database,
                                 material_path)
from goniometer.results import SimulationResult, SliceData
from goniometer.slices import SliceGrid, cell_index, light_direction
from goniometer.stack import Interface, Lambertian, Medium, Stack
from goniometer.cache import package_key
from models._jit import APPLICATION, njit
from models import registry
from models.base import ModelError
from models.compare import comparison_side, evaluate

REPORT_FORMAT = "goniometer.report"
REPORT_VERSION = 1
CACHE_FORMAT = "goniometer.report-cache"
CACHE_VERSION = 1
#: bump when the figures change in a way the module source hash would not capture
FIGURE_VERSION = 1
ASSETS = Path(__file__).resolve().parent / "assets"

#: the paper's colours (figures 5-10) for its models; others get FALLBACK_COLOURS in name order
PAPER_COLOURS = {
    "ww09": "#e41a1c",            # red
    "elek10": "#ff8c00",          # orange
    "belcour-fwd": "#00bcd4",     # cyan
    "belcour-sym": "#1f4fd8",     # blue
    "ww-bati19": "#e377c2",       # pink (figure 10, eq. 5)
    "belcour-bati19": "#2ca02c",  # green (figure 10, eq. 6)
    "belcour-btdf": "#009aa8",    # teal: Belcour forward on slabs (cyan in figure 9)
}
FALLBACK_COLOURS = ("#8c564b", "#9467bd", "#7f7f7f", "#bcbd22", "#393b79", "#637939", "#8c6d31",
                    "#843c39", "#7b4173", "#17becf")
PAPER_MARKERS = {"ww09": "o", "elek10": "s", "ww-bati19": "D", "belcour-fwd": "^", "belcour-sym": "v",
                 "belcour-bati19": "P", "belcour-btdf": "^"}
FALLBACK_MARKERS = ("X", "*", "h", "<", ">", "p", "d", "8")

#: parameters reported per material, in display order, with their labels
PARAM_KEYS = ("alpha0", "alpha1", "tau", "rho", "eta1")
PARAM_LABELS = {"alpha0": "α0", "alpha1": "α1", "tau": "τ", "rho": "ρ", "eta1": "η1",
                "paper_name": "name", "name": "material"}

#: verdict thresholds of the reproduction checks (fraction of comparisons that agree)
HOLDS_AT = 0.9
PARTLY_AT = 0.5
#: "similar" / "close" / "indistinguishable" / "identical" as error ratios, fixed before looking
SIMILAR_RATIO = 1.25
CLOSE_RATIO = 1.5
INDISTINGUISHABLE_RATIO = 1.1
IDENTICAL_REL = 1e-6

#: precision of the model slices kept in the cache (for figures only)
SLICE_CACHE_MANTISSA_BITS = 11
#: top views are exposed so that this fraction of the projected solid angle saturates
SATURATED_FRACTION = 0.005
DISK_PX = 180          # top-view disk diameter (pixels)
ORDER_DISK_PX = 130    # bounce-order disk diameter
ISO_LEVELS = 10        # luminance isovalue bands
DPI = 100
PNG_COMPRESSION = 3    # zlib level: as small as 9 on these images, and 5-10x faster

Progress = Callable[[int, int, str], None]


class ReportError(ValueError):
    """Bad input for a report (not a results directory, no materials, unreadable file, unknown
    model); the message names the file or the problem."""


# ---------------------------------------------------------------------- data classes

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
    ``failed`` mapping for models that raised); ``slices`` maps a model to (top, internal)."""

    material: ReportMaterial
    evaluation: dict
    key: str
    slices: dict[str, tuple[np.ndarray, np.ndarray]] | None = None
    from_cache: bool = False
    figures: dict = field(default_factory=dict)


@dataclass
class ReportSummary:
    """What :func:`build_report` did."""

    out_dir: Path
    index_html: Path
    errors_json: Path
    materials: list[str] = field(default_factory=list)
    records: int = 0
    evaluated: list[str] = field(default_factory=list)
    reused: list[str] = field(default_factory=list)
    figures_drawn: list[str] = field(default_factory=list)
    figures_reused: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    failed: dict[str, dict[str, str]] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    reproduction: list[dict] = field(default_factory=list)
    elapsed_s: float = 0.0


# ---------------------------------------------------------------------- small helpers

_atomic_bytes = atomic.write_bytes


def _atomic_text(path: Path, text: str) -> None:
    _atomic_bytes(path, text.encode("utf-8"))


def _atomic_json(path: Path, obj: Any) -> None:
    _atomic_text(path, json.dumps(obj, indent=1, allow_nan=False) + "\n")


def _safe_part(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]", "_", s) or "_"


def material_dir(name: str) -> Path:
    """Relative directory of a material's figures and cache entry (``plastic/P1-a0_0.05``)."""
    parts = [_safe_part(p) for p in name.split("/") if p not in ("", ".", "..")]
    return Path(*parts) if parts else Path("_")


def _sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def model_code_key() -> str:
    """Hash of the sources that determine model values and errors: the ``goniometer`` and
    ``models`` packages without the application (:data:`models._jit.APPLICATION`)."""
    return package_key(("goniometer", "models"), exclude=APPLICATION)


def report_code_key() -> str:
    """Hash of the figures' code (the report package; the HTML assets do not change figures, and
    the page is rewritten on every run anyway)."""
    return package_key(("models.report",)) + f"-{FIGURE_VERSION}"


def model_style(names: Iterable[str]) -> dict[str, dict[str, str]]:
    """Colour and marker of every model: the paper's for its models, a fixed fallback palette
    (assigned in name order) for the others."""
    out: dict[str, dict[str, str]] = {}
    others = sorted(n for n in set(names) if n not in PAPER_COLOURS)
    for n in set(names):
        if n in PAPER_COLOURS:
            out[n] = {"colour": PAPER_COLOURS[n], "marker": PAPER_MARKERS.get(n, "o")}
    for i, n in enumerate(others):
        out[n] = {"colour": FALLBACK_COLOURS[i % len(FALLBACK_COLOURS)],
                  "marker": FALLBACK_MARKERS[i % len(FALLBACK_MARKERS)]}
    return out


def _fmt_value(v: Any) -> str:
    if isinstance(v, (list, tuple)):
        return "(" + ", ".join(_fmt_value(x) for x in v) + ")"
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def param_text(params: dict, key: str) -> str | None:
    """Display text of a parameter: the symbol name for tau/rho when the definition gave one."""
    if key not in params:
        return None
    name = params.get(f"{key}_name")
    return str(name) if name is not None else _fmt_value(params[key])


# ---------------------------------------------------------------------- results directory

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


# ---------------------------------------------------------------------- evaluation and its cache

def _reference_digest(path: Path, previous: dict | None) -> dict:
    st = path.stat()
    if previous and previous.get("size") == st.st_size and previous.get("mtime_ns") == st.st_mtime_ns:
        return previous
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns, "sha256": _sha256_file(path)}


def _evaluation_key(digest: str, code: str, subcells: int, models: Sequence[str] | None,
                    isotropize: str | None = None) -> str:
    doc = {"v": CACHE_VERSION, "reference": digest, "code": code, "subcells": subcells,
           "models": sorted(models) if models is not None else "all", "isotropize": isotropize}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:20]


def _cache_paths(out: Path, name: str) -> tuple[Path, Path]:
    base = out / "cache" / material_dir(name)
    return base.with_name(base.name + ".json"), base.with_name(base.name + ".h5")


def _read_json(path: Path) -> dict | None:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    return doc if isinstance(doc, dict) else None


def _judged_side(reference: SimulationResult, where: str) -> str:
    """The side ``reference`` is judged on ("brdf" or "btdf"); ReportError if the file lacks it."""
    side = comparison_side(reference.stack)
    if (reference.brdf if side == "brdf" else reference.btdf) is None:
        raise ReportError(f"{where}: the file has no {side.upper()} slices, which a {reference.stack.base}-base "
                          f"stack is judged on")
    return side


def run_evaluation(reference: SimulationResult, models: Sequence[str] | None, subcells: int,
                   isotropize: str | None = None) -> tuple[dict, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Evaluate ``models`` (None: all of the registry) on ``reference``, one model at a time so
    that one failing model does not lose the others. Returns the ``gonio evaluate --json``
    object (with ``failed``: model -> message for models that raised) and model -> (top, internal).
    """
    stack = reference.stack
    side = _judged_side(reference, stack.name)
    names = list(registry.all_models()) if models is None else list(models)
    doc = {"material": stack.name, "category": stack.category, "side": side, "models": {}, "skipped": {},
           "failed": {}}
    slices: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name in names:
        try:
            ev = evaluate(reference, [name], s=subcells, isotropize=isotropize)
        except ModelError as e:
            msg = str(e)
            doc["skipped"][name] = msg[len(name) + 2:] if msg.startswith(f"{name}: ") else msg
            continue
        except Exception as e:  # a model's bug must not sink the whole report; it is shown
            doc["failed"][name] = f"{type(e).__name__}: {e}"
            continue
        doc["models"][name] = ev.errors[name]
        for key in ("fits", "approximations"):
            if name in getattr(ev, key):
                doc.setdefault(key, {})[name] = getattr(ev, key)[name]
        ms = ev.slices[name]
        slices[name] = (ms.top, ms.internal)
    return doc, slices


def round_mantissa(a: np.ndarray, bits: int = SLICE_CACHE_MANTISSA_BITS) -> np.ndarray:
    """``a`` as float32 rounded to ``bits`` explicit mantissa bits (relative error <= 2**-(bits+1));
    the dropped bits are zero, which lets gzip + shuffle compress the slices about 2x better."""
    u = np.ascontiguousarray(a, dtype=np.float32).view(np.uint32)
    drop = 23 - bits
    u = (u + np.uint32(1 << (drop - 1))) & np.uint32((0xFFFFFFFF << drop) & 0xFFFFFFFF)
    return u.view(np.float32)


def _save_cache(json_path: Path, h5_path: Path, entry: dict, slices: dict[str, tuple[np.ndarray, np.ndarray]]) -> None:
    """The integrated model slices (for figures only: float32 rounded by :func:`round_mantissa`;
    the errors are computed at full precision and kept in the JSON) and the JSON entry."""
    h5_path.parent.mkdir(parents=True, exist_ok=True)
    with store.atomic_path(h5_path) as tmp:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = CACHE_FORMAT
            f.attrs["key"] = entry["key"]
            f.attrs["precision"] = f"float32 rounded to {SLICE_CACHE_MANTISSA_BITS} mantissa bits"
            for name, (top, internal) in slices.items():
                g = f.create_group(name)
                for part, arr in (("top", top), ("internal", internal)):
                    g.create_dataset(part, data=round_mantissa(arr), chunks=True, compression="gzip",
                                     compression_opts=4, shuffle=True)
    _atomic_json(json_path, entry)  # written last: it vouches for the slices file by its key


def _load_slices(h5_path: Path, key: str, names: Iterable[str]) -> dict[str, tuple[np.ndarray, np.ndarray]] | None:
    try:
        with h5py.File(h5_path, "r") as f:
            if f.attrs.get("key") != key:
                return None
            return {n: (f[f"{n}/top"][()].astype(np.float64), f[f"{n}/internal"][()].astype(np.float64))
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


def _read_reference(path: Path) -> SimulationResult:
    try:
        return store.read(path)
    except store.StoreError as e:
        raise ReportError(str(e) if str(path) in str(e) else f"{path}: {e}") from None


# ---------------------------------------------------------------------- geometry of the figures

@njit(cache=True)
def _pixel_cells(param: int, transmission: bool, lx: float, ly: float, lz: float, size: int,
                 n_theta: int, n_phi: int):
    """Cell (i, j) of every pixel of an orthographic top view (row 0 at +y); -1 outside the disk."""
    ii = np.full((size, size), -1, dtype=np.int64)
    jj = np.full((size, size), -1, dtype=np.int64)
    for r in range(size):
        y = 1.0 - (2.0 * r + 1.0) / size
        for c in range(size):
            x = (2.0 * c + 1.0) / size - 1.0
            rr = x * x + y * y
            if rr >= 1.0:
                continue
            z = math.sqrt(1.0 - rr)
            vz = -z if transmission else z
            i, j = cell_index(param, transmission, lx, ly, lz, x, y, vz, n_theta, n_phi)
            ii[r, c] = i
            jj[r, c] = j
    return ii, jj


@dataclass
class PixelMap:
    """Where every top-view pixel reads its value: ``ii``/``jj`` cells, ``ok`` valid pixels."""

    ii: np.ndarray
    jj: np.ndarray
    ok: np.ndarray
    inside: np.ndarray
    size: int

    def sample(self, cells: np.ndarray) -> np.ndarray:
        """``cells`` (..., n_theta, n_phi) -> (..., size, size), NaN where invalid."""
        out = np.full(cells.shape[:-2] + (self.size, self.size), np.nan)
        out[..., self.ok] = cells[..., self.ii[self.ok], self.jj[self.ok]]
        return out


def pixel_map(grid: SliceGrid, light: np.ndarray, mask: np.ndarray, size: int) -> PixelMap:
    ii, jj = _pixel_cells(grid.code, grid.transmission, float(light[0]), float(light[1]), float(light[2]), size,
                          grid.n_theta, grid.n_phi)
    inside = ii >= 0
    ok = inside.copy()
    ok[inside] = mask[ii[inside], jj[inside]]
    return PixelMap(ii, jj, ok, _disk(size), size)


def _disk(size: int) -> np.ndarray:
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    return c[None, :] ** 2 + c[::-1, None] ** 2 < 1.0


def _nearest_columns(centres: np.ndarray, azimuth: float) -> np.ndarray:
    d = np.abs((centres - azimuth + 180.0) % 360.0 - 180.0)
    cols = np.flatnonzero(d <= d.min() + 1e-6)[:2]
    return cols if len(cols) == 2 else np.array([cols[0], cols[0]])


def _cell_direction(grid: SliceGrid, light: np.ndarray, theta_deg: float, azimuth_deg: float) -> np.ndarray | None:
    t, a = math.radians(theta_deg), math.radians(azimuth_deg)
    d = np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])
    if grid.parametrization == "half":
        d = 2.0 * float(light @ d) * d - light
        if d[2] <= 0.0:
            return None
    if grid.transmission:
        d[2] = -d[2]
    return d


def plane_cells(grid: SliceGrid, light: np.ndarray, phi_l_deg: float, mask: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cells along the plane of incidence: ``(x_deg, rows, cols)`` sorted by ``x``.

    ``x`` is the signed elevation of the cell-centre direction ``v`` in the plane, positive on
    the side of the mirror / straight-through direction (``phi_v = phi_l + 180``); ``cols`` (n, 2)
    are the two columns next to the plane (values are their mean); masked cells are left out.
    """
    e = np.array([math.cos(math.radians(phi_l_deg)), math.sin(math.radians(phi_l_deg)), 0.0])
    centres, th = grid.phi_centers_deg(), grid.theta_centers_deg()
    pts = []
    for az in (phi_l_deg, phi_l_deg + 180.0):
        cols = _nearest_columns(centres, az % 360.0)
        for i in range(grid.n_theta):
            if not mask[i, cols].all():
                continue
            v = _cell_direction(grid, light, float(th[i]), az)
            if v is None:
                continue
            pts.append((math.degrees(math.atan2(-float(v @ e), abs(float(v[2])))), i, cols[0], cols[1]))
    pts.sort()
    arr = np.array(pts, dtype=float).reshape(-1, 4)
    return arr[:, 0], arr[:, 1].astype(int), arr[:, 2:].astype(int)


def remap(f: np.ndarray) -> np.ndarray:
    """The paper's display remap ``log(1 + sqrt(f))`` (negative values clipped to 0)."""
    return np.log1p(np.sqrt(np.maximum(f, 0.0)))


def exposure(g: np.ndarray, omega: np.ndarray, mask: np.ndarray, saturated: float = SATURATED_FRACTION) -> float:
    """The value of ``g`` (n_theta, n_phi) exceeded on only ``saturated`` of the valid projected
    solid angle: a display scale that a sharp peak (tiny solid angle) does not dictate."""
    w = (omega * mask).ravel()
    v = g.ravel()
    if not np.any(w > 0):
        return 1.0
    order = np.argsort(v, kind="stable")
    cw = np.cumsum(w[order])
    val = float(v[order[min(int(np.searchsorted(cw, (1.0 - saturated) * cw[-1])), v.size - 1)]])
    if val > 0.0:
        return val
    top = float(np.max(v[w > 0]))
    return top if top > 0.0 else 1.0


def luminance(rgb: np.ndarray, axis: int = 0) -> np.ndarray:
    """Rec. 709 luminance along ``axis`` (the channel axis)."""
    w = np.array([0.2126, 0.7152, 0.0722]).reshape((3,) + (1,) * (rgb.ndim - axis - 1))
    return np.sum(rgb * w, axis=axis)


# ---------------------------------------------------------------------- raster panels (numpy -> PNG)

def _cmap(name: str):
    import matplotlib
    return matplotlib.colormaps[name]


def _rgb_panel(rgb: np.ndarray, scale: float, pm: PixelMap, factor: float = 1.0) -> np.ndarray:
    """(3, S, S) cell values -> (S, S, 3) image of ``factor * g(f) / scale``."""
    img = np.moveaxis(np.clip(factor * remap(pm.sample(rgb)) / scale, 0.0, 1.0), 0, -1)
    return _frame(img, pm)


def _iso_panel(lum: np.ndarray, scale: float, pm: PixelMap, levels: int = ISO_LEVELS) -> np.ndarray:
    """Luminance isovalue bands of ``g(L) / scale`` in false colour (viridis), with black band
    boundaries; values above the scale are white."""
    g = remap(pm.sample(lum)) / scale
    band = np.where(np.isfinite(g), np.floor(np.clip(g, 0.0, None) * levels), -1).astype(int)
    band = np.minimum(band, levels)
    colours = _cmap("viridis")(np.linspace(0.0, 1.0, levels))[:, :3]
    img = np.ones(band.shape + (3,))
    inside = (band >= 0) & (band < levels)
    img[inside] = colours[band[inside]]
    edge = np.zeros(band.shape, bool)
    edge[:, 1:] |= (band[:, 1:] != band[:, :-1]) & (band[:, 1:] >= 0) & (band[:, :-1] >= 0)
    edge[1:, :] |= (band[1:, :] != band[:-1, :]) & (band[1:, :] >= 0) & (band[:-1, :] >= 0)
    img[edge] = 0.1
    return _frame(img, pm)


def _diverging_panel(d: np.ndarray, lim: float, pm: PixelMap) -> np.ndarray:
    """(S, S) signed values -> RdBu_r colours over [-lim, lim]."""
    t = np.clip(0.5 + 0.5 * d / lim, 0.0, 1.0)
    img = _cmap("RdBu_r")(np.nan_to_num(t, nan=0.5))[..., :3]
    return _frame(img, pm, valid=np.isfinite(d))


def _frame(img: np.ndarray, pm: PixelMap, valid: np.ndarray | None = None) -> np.ndarray:
    ok = pm.ok if valid is None else (pm.ok & valid)
    out = np.where(ok[..., None], np.nan_to_num(img), 0.82)   # masked cells: light grey
    out[~pm.inside] = 1.0
    ring = pm.inside & ~np.pad(pm.inside, 1)[2:, 1:-1] | pm.inside & ~np.pad(pm.inside, 1)[1:-1, 2:] \
        | pm.inside & ~np.pad(pm.inside, 1)[:-2, 1:-1] | pm.inside & ~np.pad(pm.inside, 1)[1:-1, :-2]
    out[ring] = 0.45
    return out


def _mark_light(img: np.ndarray, light: np.ndarray) -> np.ndarray:
    """Hollow yellow ring (dark outline) at the top-view position of the light direction; the
    values under its centre stay visible."""
    s = img.shape[0]
    cx = (light[0] + 1.0) / 2.0 * s - 0.5
    cy = (1.0 - light[1]) / 2.0 * s - 0.5
    yy, xx = np.mgrid[0:s, 0:s]
    r = np.sqrt((xx - cx) ** 2 + (yy - cy) ** 2)
    rad = max(4.0, s / 40)
    img[(r >= rad - 2.2) & (r <= rad + 1.2)] = (0.1, 0.1, 0.1)
    img[(r >= rad - 1.2) & (r <= rad + 0.2)] = (1.0, 0.85, 0.0)
    return img


def _compose(rows: list[list[np.ndarray]], gap: int = 8) -> np.ndarray:
    """Panels (float RGB in [0, 1]) on a white canvas, row by row."""
    h = max(p.shape[0] for row in rows for p in row)
    w = max(sum(p.shape[1] for p in row) + gap * (len(row) - 1) for row in rows)
    canvas = np.ones((len(rows) * h + gap * (len(rows) - 1), w, 3))
    for r, row in enumerate(rows):
        x = 0
        for p in row:
            y = r * (h + gap)
            canvas[y:y + p.shape[0], x:x + p.shape[1]] = p
            x += p.shape[1] + gap
    return canvas


def _write_png(path: Path, img: np.ndarray) -> None:
    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray((np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)).save(buf, format="PNG", compress_level=PNG_COMPRESSION)
    _atomic_bytes(path, buf.getvalue())


def _save_figure(fig, path: Path) -> None:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, pil_kwargs={"compress_level": PNG_COMPRESSION})
    _atomic_bytes(path, buf.getvalue())


# ---------------------------------------------------------------------- per-material figures

@dataclass
class _Incident:
    """Everything the figures of one incident direction need."""

    m: int
    theta: float
    phi: float
    light: np.ndarray
    ref: np.ndarray            # (3, nt, nph) total reference
    ref_se: np.ndarray
    ref_internal: np.ndarray
    ref_internal_se: np.ndarray
    orders: np.ndarray         # (K, 3, nt, nph)
    mask: np.ndarray
    omega: np.ndarray
    models: dict[str, tuple[np.ndarray, np.ndarray]]   # (top, internal), each (3, nt, nph)


def _incidents(ref: SimulationResult, sd: SliceData, slices: dict, which: list[int]) -> Iterable[_Incident]:
    internal = sd.orders[:, 1:].astype(np.float64).sum(axis=1)
    se_int = sd.stderr_internal if sd.stderr_internal is not None else sd.stderr
    for m in which:
        th, ph = float(ref.theta_deg[m]), float(ref.phi_deg[m])
        yield _Incident(m, th, ph, light_direction(th, ph), sd.value[m], sd.stderr[m], internal[m], se_int[m],
                        sd.orders[m].astype(np.float64), sd.mask[m], sd.proj_solid_angle[m],
                        {n: (t[m], i[m]) for n, (t, i) in slices.items()})


def _figure_incidents(ref: SimulationResult, wanted: Sequence[float] | None) -> list[int]:
    if wanted is None:
        return list(range(len(ref.theta_deg)))
    return [m for m, t in enumerate(ref.theta_deg) if any(abs(float(t) - float(w)) < 1e-6 for w in wanted)]


def draw_material_figures(ref: SimulationResult, slices: dict[str, tuple[np.ndarray, np.ndarray]],
                          fig_dir: Path, rel: str, styles: dict, incidents: Sequence[float] | None) -> dict:
    """Draw every figure of one material into ``fig_dir``; returns their paths relative to the
    report (``rel`` is ``fig_dir`` relative to it) for the HTML: ``{"incidents": [...], "energy": ...}``."""
    side = comparison_side(ref.stack)
    sd = ref.brdf if side == "brdf" else ref.btdf
    entries = []
    for inc in _incidents(ref, sd, slices, _figure_incidents(ref, incidents)):
        plane = f"plane_m{inc.m}.png"
        _save_figure(_plane_figure(inc, sd.grid, side, styles, ref.stack.name, ref.settings.rays), fig_dir / plane)
        tops, diff_scale, lum_scale = _top_views(inc, sd.grid, fig_dir)
        orders = f"orders_m{inc.m}.png"
        _write_png(fig_dir / orders, _orders_image(inc, sd.grid))
        entries.append({"index": inc.m, "theta": inc.theta, "phi": inc.phi, "plane": f"{rel}/{plane}",
                        "orders": f"{rel}/{orders}", "top": {k: f"{rel}/{v}" for k, v in tops.items()},
                        "diff_scale": diff_scale, "scale": lum_scale})
    _save_figure(_energy_figure(ref, sd, side), fig_dir / "energy.png")
    return {"incidents": entries, "energy": f"{rel}/energy.png", "orders_k": int(sd.orders.shape[1])}


def plot_file(path: str | Path, out_dir: str | Path, models: Sequence[str] | None = None,
              incidents: Sequence[float] | None = None, subcells: int = 5,
              isotropize: str | None = None) -> dict:
    """The per-material figures of the report for one simulated file, written into ``out_dir``.

    ``models``: names to draw beside the reference (``["all"]``: every model that supports the
    stack; None or empty: the reference alone), integrated onto the file's cells exactly as
    ``gonio evaluate`` does (``subcells``, ``isotropize``). ``incidents``: polar angles (degrees)
    of the file's incident directions to draw (None: all). Returns ``{"figures": [paths],
    "evaluation": the gonio evaluate --json object or None}``. Raises ReportError for a bad file or
    an incident angle the file does not hold, ModelError for an unknown or unsupported model.
    """
    ref = _read_reference(Path(path))
    if incidents is not None:
        have = [float(t) for t in ref.theta_deg]
        missing = [w for w in incidents if not any(abs(t - float(w)) < 1e-6 for t in have)]
        if missing:
            raise ReportError(f"{path}: no incident direction at theta = {', '.join(f'{w:g}' for w in missing)} deg "
                              f"(the file has {', '.join(f'{t:g}' for t in have)})")
    _judged_side(ref, str(path))
    slices: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    doc = None
    if models:
        names = None if list(models) == ["all"] else list(models)
        ev = evaluate(ref, names, s=subcells, isotropize=isotropize)
        slices = {n: (ms.top, ms.internal) for n, ms in ev.slices.items()}
        doc = ev.to_json()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figs = draw_material_figures(ref, slices, out, ".", model_style(list(slices)), incidents)
    paths = [out / "energy.png"]
    for e in figs["incidents"]:
        paths += [out / e["plane"], out / e["orders"]] + [out / t for t in e["top"].values()]
    return {"figures": [str(p.resolve()) for p in paths], "evaluation": doc}


#: upper bound drawn for a cell no path reached: 3 / (N Omega) is the 95 % upper limit of its value
#: (no hit among N rays of weight <= 1: the expected count N f Omega is below 3 at 95 %)
ZERO_HIT_BOUND = 3.0


def _plane_figure(inc: _Incident, grid: SliceGrid, side: str, styles: dict, title: str, rays: int):
    """The plane-of-incidence figure. The grey band is the reference +- 2 standard errors; where no
    path reached a cell (value 0, standard error 0: tiny cells near the pole of half slices at low
    ray counts) it spans [0, 3 / (N Omega)] instead, the 95 % upper limit, so an empty cell does not
    look like a confident zero."""
    from matplotlib.figure import Figure
    x, rows, cols = plane_cells(grid, inc.light, inc.phi, inc.mask)
    # (title, reference cells, their standard error, the model part drawn from (top, internal))
    if side == "brdf":
        parts = [("total", inc.ref, inc.ref_se, lambda t, i: t + i),
                 ("internal paths (order 1 / top lobe dropped)", inc.ref_internal, inc.ref_internal_se,
                  lambda t, i: i)]
    else:
        parts = [("BTDF", inc.ref, inc.ref_se, lambda t, i: t + i)]
    width = 4.0 * len(parts) + 1.6
    fig = Figure(figsize=(width, 2.9), dpi=DPI)   # fixed layout: constrained layout costs ~0.3 s a figure
    fig.subplots_adjust(left=0.6 / width, right=1.0 - 1.55 / width, bottom=0.17, top=0.84, wspace=0.22)
    axes = fig.subplots(1, len(parts), squeeze=False)[0]

    def along(cells: np.ndarray) -> np.ndarray:
        return 0.5 * (cells[rows, cols[:, 0]] + cells[rows, cols[:, 1]])

    bound = along(ZERO_HIT_BOUND / (max(rays, 1) * np.where(inc.omega > 0, inc.omega, np.inf)))
    for ax, (label, ref_cells, se_cells, pick) in zip(axes, parts):
        lum = along(luminance(ref_cells))
        se = along(luminance(se_cells))
        upper = np.where(lum > 0, lum + 2 * se, bound)
        ax.fill_between(x, remap(lum - 2 * se), remap(upper), color="0.8", lw=0,
                        label="reference ±2σ\n(no hit: 95% bound)")
        ax.plot(x, remap(lum), "k--", lw=1.3, label="reference")
        for name, (top, internal) in inc.models.items():
            st = styles.get(name, {"colour": "k"})
            ax.plot(x, remap(along(luminance(pick(top, internal)))), "-", color=st["colour"], lw=1.1, label=name)
        ax.axvline(inc.theta, color="0.5", lw=0.6, ls=":")
        ax.set_xlim(-90, 90)
        ax.set_xticks([-90, -60, -30, 0, 30, 60, 90])
        ax.set_xlabel("signed θ_v (deg), > 0 on the " + ("mirror" if side == "brdf" else "straight-through")
                      + " side", fontsize=8)
        ax.set_title(label, fontsize=9)
        ax.tick_params(labelsize=8)
    axes[0].set_ylabel("log(1 + √f), luminance", fontsize=8)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="center right", fontsize=7, frameon=False)
    fig.suptitle(f"{title}: plane of incidence, θ_l = {inc.theta:g}°", fontsize=9)
    return fig


def _top_views(inc: _Incident, grid: SliceGrid, fig_dir: Path) -> tuple[dict[str, str], float, float]:
    """Reference and model top views, one PNG each with three disks: RGB, luminance isovalues and
    the signed difference of g(L) to the reference (for the reference: its 2-sigma noise), all
    on scales shared by the reference and the models. Returns file names, the difference scale
    and the luminance scale."""
    pm = pixel_map(grid, inc.light, inc.mask, DISK_PX)
    scale = exposure(np.max(remap(inc.ref), axis=0), inc.omega, inc.mask)
    lum_ref = luminance(inc.ref)
    lum_scale = exposure(remap(lum_ref), inc.omega, inc.mask)
    g_lum_ref = remap(pm.sample(lum_ref))
    diffs = {n: remap(pm.sample(luminance(t + i))) - g_lum_ref for n, (t, i) in inc.models.items()}
    allabs = np.concatenate([np.abs(d[np.isfinite(d)]) for d in diffs.values()]) if diffs else np.zeros(0)
    lim = float(np.percentile(allabs, 99)) if allabs.size else 0.0
    lim = max(lim, 1e-3 * lum_scale, 1e-12)
    noise = remap(pm.sample(lum_ref + 2.0 * luminance(inc.ref_se))) - g_lum_ref
    out = {}
    panels = {"reference": (inc.ref, noise)}
    panels.update({n: (t + i, diffs[n]) for n, (t, i) in inc.models.items()})
    for name, (cells, third) in panels.items():
        a = _mark_light(_rgb_panel(cells, scale, pm), inc.light)
        b = _mark_light(_iso_panel(luminance(cells), lum_scale, pm), inc.light)
        c = _mark_light(_diverging_panel(third, lim, pm), inc.light)
        fname = f"top_m{inc.m}_{_safe_part(name)}.png"
        _write_png(fig_dir / fname, _compose([[a, b, c]]))
        out[name] = fname
    return out, lim, lum_scale


def _orders_image(inc: _Incident, grid: SliceGrid) -> np.ndarray:
    """Figure 13: per bounce order (columns), RGB (orders >= 2 doubled) over isovalues (each
    order exposed on its own range, see :func:`exposure`)."""
    pm = pixel_map(grid, inc.light, inc.mask, ORDER_DISK_PX)
    scale = exposure(np.max(remap(inc.ref), axis=0), inc.omega, inc.mask)
    top, bottom = [], []
    for k in range(inc.orders.shape[0]):
        cells = inc.orders[k]
        top.append(_mark_light(_rgb_panel(cells, scale, pm, factor=1.0 if k == 0 else 2.0), inc.light))
        lum = luminance(cells)
        bottom.append(_mark_light(_iso_panel(lum, exposure(remap(lum), inc.omega, inc.mask), pm), inc.light))
    return _compose([top, bottom])


def order_energy(sd: SliceData) -> np.ndarray:
    """Luminance of the energy ``sum_cells f Omega`` per incident and bounce order, (M, K)."""
    lum = luminance(sd.orders.astype(np.float64), axis=2)          # (M, K, nt, nph)
    return np.einsum("mkij,mij->mk", lum, sd.proj_solid_angle)


def _energy_figure(ref: SimulationResult, sd: SliceData, side: str):
    from matplotlib.figure import Figure
    e = order_energy(sd)
    K = e.shape[1]
    fig = Figure(figsize=(5.0, 2.6), dpi=DPI)
    fig.subplots_adjust(left=0.13, right=0.78, bottom=0.17, top=0.89)
    ax = fig.add_subplot()
    xs = np.arange(e.shape[0])
    bottom = np.zeros(e.shape[0])
    colours = _cmap("viridis")(np.linspace(0.0, 0.9, K))
    for k in range(K):
        label = f"order {k + 1}" + ("+" if k == K - 1 else "")
        ax.bar(xs, e[:, k], bottom=bottom, color=colours[k], label=label, width=0.7)
        bottom += e[:, k]
    ax.set_xticks(xs, [f"{t:g}°" for t in ref.theta_deg])
    ax.set_xlabel("θ_l", fontsize=8)
    ax.set_ylabel(("reflected" if side == "brdf" else "transmitted") + " energy (luminance)", fontsize=8)
    ax.tick_params(labelsize=8)
    ax.legend(fontsize=7, frameon=False, loc="center left", bbox_to_anchor=(1.0, 0.5))
    ax.set_title(f"{ref.stack.name}: energy per bounce order", fontsize=9)
    return fig


# ---------------------------------------------------------------------- error records and tables

def error_records(results: list[MaterialResult]) -> list[dict]:
    """One record per (material, evaluated model): material, category, paper_name, parameters,
    model, side, internal, total (the error objects of ``gonio evaluate --json``)."""
    out = []
    for r in results:
        m = r.material
        for model, errs in r.evaluation["models"].items():
            rec = {"material": m.name, "category": m.category, "paper_name": m.paper_name}
            for k in PARAM_KEYS:
                if k in m.params:
                    rec[k] = m.params[k]
                    if f"{k}_name" in m.params:
                        rec[f"{k}_name"] = m.params[f"{k}_name"]
            rec.update({"model": model, "side": r.evaluation["side"], "internal": errs["internal"],
                        "total": errs["total"]})
            out.append(rec)
    return out


def _sort_key(m: ReportMaterial) -> tuple:
    p = m.params
    return (p.get("alpha0", 0.0), m.paper_name, p.get("alpha1", 0.0), str(p.get("eta1", "")), m.name)


CSV_COLUMNS = ("material", "category", "paper_name", *PARAM_KEYS, "model", "side",
               "internal_rmse_mean", "internal_rmse_r", "internal_rmse_g", "internal_rmse_b",
               "internal_rmse_luminance", "internal_noise_floor_mean", "internal_noise_floor_luminance",
               "total_rmse_mean", "total_rmse_luminance", "total_noise_floor_mean", "rank_internal")


def category_csv(results: list[MaterialResult]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for r in sorted(results, key=lambda r: _sort_key(r.material)):
        m = r.material
        models = r.evaluation["models"]
        ranked = sorted(models, key=lambda n: models[n]["internal"]["rmse_mean"])
        for name in models:
            i, t = models[name]["internal"], models[name]["total"]
            w.writerow([m.name, m.category, m.paper_name, *[param_text(m.params, k) or "" for k in PARAM_KEYS],
                        name, r.evaluation["side"], _g(i["rmse_mean"]), *[_g(x) for x in i["rmse"]],
                        _g(i["rmse_luminance"]), _g(i["noise_floor_mean"]), _g(i["noise_floor_luminance"]),
                        _g(t["rmse_mean"]), _g(t["rmse_luminance"]), _g(t["noise_floor_mean"]),
                        ranked.index(name) + 1])
    return buf.getvalue()


def _g(x: float) -> str:
    return f"{x:.6g}"


def category_markdown(category: str, results: list[MaterialResult]) -> str:
    """Markdown tables (materials x models) of the channel-mean RMSE, best per row in bold."""
    results = sorted(results, key=lambda r: _sort_key(r.material))
    side = results[0].evaluation["side"] if results else "brdf"
    models = _ordered_models(results)
    keys = [k for k in PARAM_KEYS if any(k in r.material.params for r in results)]
    parts = [f"# {category}: RMSE of Bati 2019 eq. 4, mean over R, G, B\n",
             f"{len(results)} material(s). Side compared: {side.upper()}. Lower is better; the best model of "
             f"each row is in bold; `noise floor` is the error a perfect model would show against this "
             f"reference. Full numbers (per channel, luminance): `{category}.csv`, `../errors.json`.\n"]
    sections = [("internal", "internal paths (bounce order 1 and the models' top lobe dropped)")] \
        if side == "brdf" else [("internal", "BTDF")]
    if side == "brdf":
        sections.append(("total", "total BRDF"))
    for part, label in sections:
        parts.append(f"\n## {label}\n")
        head = ["material", "name", *[PARAM_LABELS[k] for k in keys], *models, "noise floor"]
        parts.append("| " + " | ".join(head) + " |")
        parts.append("|" + "---|" * len(head))
        for r in results:
            errs = r.evaluation["models"]
            vals = {n: errs[n][part]["rmse_mean"] for n in models if n in errs}
            best = min(vals, key=vals.get) if vals else None
            cells = [f"**{vals[n]:.3e}**" if n == best else (f"{vals[n]:.3e}" if n in vals else "–")
                     for n in models]
            nf = next(iter(errs.values()))[part]["noise_floor_mean"] if errs else float("nan")
            row = [r.material.name, r.material.paper_name,
                   *[param_text(r.material.params, k) or "" for k in keys], *cells, f"{nf:.1e}"]
            parts.append("| " + " | ".join(row) + " |")
    return "\n".join(parts) + "\n"


def _ordered_models(results: list[MaterialResult]) -> list[str]:
    order = list(registry.all_models())
    seen = {n for r in results for n in r.evaluation["models"]}
    return [n for n in order if n in seen] + sorted(seen - set(order))


# ---------------------------------------------------------------------- figure-4 plots

def _label_keys(results: list[MaterialResult]) -> list[str]:
    """Parameters (besides alpha0) that a paper name does not determine within a category."""
    keys = []
    for k in PARAM_KEYS[1:]:
        by_name: dict[str, set] = {}
        for r in results:
            if k in r.material.params:
                by_name.setdefault(r.material.paper_name, set()).add(json.dumps(r.material.params[k]))
        if any(len(v) > 1 for v in by_name.values()):
            keys.append(k)
    return keys


def _plot_category(ax, category: str, results: list[MaterialResult], styles: dict) -> None:
    results = sorted(results, key=lambda r: _sort_key(r.material))
    extra = _label_keys(results)
    xs = np.arange(len(results))
    labels = [r.material.paper_name + "".join(f"\n{PARAM_LABELS[k]}={param_text(r.material.params, k)}"
                                              for k in extra) for r in results]
    groups = [r.material.params.get("alpha0") for r in results]
    for name in _ordered_models(results):
        st = styles[name]
        ys = np.array([r.evaluation["models"][name]["internal"]["rmse_mean"] if name in r.evaluation["models"]
                       else np.nan for r in results])
        for g in dict.fromkeys(groups):
            sel = np.array([x == g for x in groups])
            ax.plot(xs[sel], ys[sel], "-", color=st["colour"], lw=0.8, alpha=0.6)
        ax.plot(xs, ys, st["marker"], color=st["colour"], ms=5, ls="none", label=name)
    nf = [next(iter(r.evaluation["models"].values()))["internal"]["noise_floor_mean"] if r.evaluation["models"]
          else np.nan for r in results]
    ax.plot(xs, nf, "_", color="0.4", ms=10, mew=1.5, ls="none", label="noise floor")
    for i in range(1, len(groups)):
        if groups[i] != groups[i - 1]:
            ax.axvline(i - 0.5, color="0.6", lw=0.8)
    starts = [i for i in range(len(groups)) if i == 0 or groups[i] != groups[i - 1]]
    for s, e in zip(starts, starts[1:] + [len(groups)]):
        if groups[s] is not None:
            ax.text((s + e - 1) / 2, 1.01, f"α0 = {groups[s]:g}", transform=ax.get_xaxis_transform(),
                    ha="center", va="bottom", fontsize=8)
    ax.set_yscale("log")
    from matplotlib.ticker import NullFormatter
    ax.yaxis.set_minor_formatter(NullFormatter())
    ax.set_xticks(xs, labels, fontsize=7)
    ax.set_xlim(-0.6, len(results) - 0.4)
    side = results[0].evaluation["side"] if results else "brdf"
    what = "internal paths, order 1 dropped" if side == "brdf" else "BTDF"
    ax.set_ylabel(f"RMSE ({what})\nmean over R, G, B", fontsize=8)
    ax.set_title(category, fontsize=10, pad=14)
    ax.tick_params(axis="y", labelsize=8)
    ax.legend(fontsize=7, frameon=False, loc="center left", bbox_to_anchor=(1.0, 0.5))


def _errors_figure(groups: dict[str, list[MaterialResult]], styles: dict):
    from matplotlib.figure import Figure
    n = max(len(v) for v in groups.values())
    fig = Figure(figsize=(max(5.0, 0.32 * n + 2.8), 3.0 * len(groups)), dpi=DPI, layout="constrained")
    axes = fig.subplots(len(groups), 1, squeeze=False)[:, 0]
    for ax, (cat, res) in zip(axes, groups.items()):
        _plot_category(ax, cat, res, styles)
    return fig


# ---------------------------------------------------------------------- reproduction checks

WW09, ELEK, WW_BATI, B_FWD, B_SYM, B_BATI, B_BTDF = ("ww09", "elek10", "ww-bati19", "belcour-fwd", "belcour-sym",
                                                   "belcour-bati19", "belcour-btdf")


@dataclass
class _Row:
    name: str
    category: str
    params: dict
    errors: dict   # model -> {"internal": E, "total": E}


def _verdict(passed: int, n: int) -> str:
    if n == 0:
        return "not testable"
    f = passed / n
    return "holds" if f >= HOLDS_AT else ("partly" if f >= PARTLY_AT else "does not hold")


def _check(cid: str, source: str, paper: str, test: str, models: Sequence[str], outcomes: list[tuple[bool, bool, str]],
           missing: Sequence[str], n_materials: int) -> dict:
    """A check's record; ``outcomes``: (agrees, noise_limited, detail) per comparison."""
    n = len(outcomes)
    passed = sum(1 for o in outcomes if o[0])
    note = ""
    if n == 0:
        if missing:
            note = f"not evaluated: {', '.join(missing)}"
        elif n_materials == 0:
            note = "no material of this kind in the results"
        else:
            note = "nothing to compare"
    elif missing:
        note = f"not evaluated on every material: {', '.join(missing)}"
    return {"id": cid, "source": source, "paper": paper, "test": test, "models": list(models), "n": n,
            "agree": passed, "fraction": (passed / n if n else None), "verdict": _verdict(passed, n),
            "noise_limited": sum(1 for o in outcomes if o[1]), "note": note,
            "details": [o[2] for o in outcomes]}


def _val(row: _Row, model: str, part: str, key: str = "rmse_mean"):
    e = row.errors.get(model)
    return None if e is None else e[part][key]


def _group_min(row: _Row, models: Sequence[str], part: str) -> float | None:
    vals = [_val(row, m, part) for m in models]
    return None if any(v is None for v in vals) else min(vals)


def _nf(row: _Row, part: str) -> float:
    return next(iter(row.errors.values()))[part]["noise_floor_mean"] if row.errors else 0.0


def _missing(rows: list[_Row], models: Sequence[str]) -> list[str]:
    return [m for m in models if any(m not in r.errors for r in rows)]


def _label(models: Sequence[str]) -> str:
    return models[0] if len(models) == 1 else "min(" + ", ".join(models) + ")"


def _order_check(cid, source, paper, rows: list[_Row], chain: Sequence[Sequence[str]], part="internal") -> dict:
    """Every row: value(chain[0]) < value(chain[1]) < ... (each item a group of models: its min)."""
    models = [m for g in chain for m in g]
    outcomes = []
    for r in rows:
        vals = [_group_min(r, g, part) for g in chain]
        if any(v is None for v in vals):
            continue
        ok = all(a < b for a, b in zip(vals, vals[1:]))
        noise = any(abs(b - a) < _nf(r, part) for a, b in zip(vals, vals[1:]))
        outcomes.append((ok, noise, f"{r.name}: " + " < ".join(f"{_label(g)} {v:.3g}" for g, v in zip(chain, vals))
                         + ("" if ok else "  (no)")))
    test = " < ".join(_label(g) for g in chain) + f" ({part} RMSE, channel mean), per material"
    return _check(cid, source, paper, test, models, outcomes, _missing(rows, models), len(rows))


def _ratio_check(cid, source, paper, rows: list[_Row], a: Sequence[str], b: Sequence[str], limit: float,
                 symmetric: bool, part="internal") -> dict:
    """Every row: a / b <= limit (``symmetric``: max/min <= limit)."""
    models = [*a, *b]
    outcomes = []
    for r in rows:
        va, vb = _group_min(r, a, part), _group_min(r, b, part)
        if va is None or vb is None or vb <= 0 or va <= 0:
            continue
        ratio = va / vb
        q = max(ratio, 1 / ratio) if symmetric else ratio
        ok = q <= limit
        outcomes.append((ok, False, f"{r.name}: {_label(a)} / {_label(b)} = {ratio:.3g}" + ("" if ok else "  (no)")))
    rel = f"max/min of {_label(a)} and {_label(b)} <= {limit:g}" if symmetric else \
        f"{_label(a)} / {_label(b)} <= {limit:g}"
    return _check(cid, source, paper, f"{rel} ({part} RMSE, channel mean), per material", models, outcomes,
                  _missing(rows, models), len(rows))


def _identical_check(cid, source, paper, rows: list[_Row], a: str, b: str, part="internal") -> dict:
    outcomes = []
    for r in rows:
        va, vb = _val(r, a, part), _val(r, b, part)
        if va is None or vb is None:
            continue
        ok = abs(va - vb) <= IDENTICAL_REL * max(abs(va), abs(vb), 1e-300)
        outcomes.append((ok, False, f"{r.name}: {a} {va:.6g}, {b} {vb:.6g}" + ("" if ok else "  (differ)")))
    return _check(cid, source, paper, f"|{a} - {b}| <= {IDENTICAL_REL:g} x error ({part} RMSE), per material",
                  [a, b], outcomes, _missing(rows, [a, b]), len(rows))


def _trend_check(cid, source, paper, rows: list[_Row], model: str, param: str) -> dict:
    """Among materials equal but for ``param``: the error grows as ``param`` decreases (every
    consecutive pair in ``param`` order)."""
    groups: dict[str, list[_Row]] = {}
    for r in rows:
        if param not in r.params or model not in r.errors:
            continue
        rest = {k: v for k, v in r.params.items() if k != param and not k.endswith("_name")}
        groups.setdefault(json.dumps(rest, sort_keys=True), []).append(r)
    outcomes = []
    for members in groups.values():
        members.sort(key=lambda r: r.params[param])
        for lo, hi in zip(members, members[1:]):
            e_lo, e_hi = _val(lo, model, "internal"), _val(hi, model, "internal")
            ok = e_lo > e_hi
            noise = abs(e_lo - e_hi) < max(_nf(lo, "internal"), _nf(hi, "internal"))
            outcomes.append((ok, noise, f"{lo.name} ({PARAM_LABELS[param]}={lo.params[param]:g}) {e_lo:.3g} > "
                                        f"{hi.name} ({PARAM_LABELS[param]}={hi.params[param]:g}) {e_hi:.3g}"
                                        + ("" if ok else "  (no)")))
    test = (f"{model}: for materials equal but for {PARAM_LABELS[param]}, error at the smaller "
            f"{PARAM_LABELS[param]} > error at the next larger one (RMSE, channel mean), per pair")
    return _check(cid, source, paper, test, [model], outcomes, _missing(rows, [model]), len(rows))


def _chromatic(v: Any) -> bool:
    return isinstance(v, (list, tuple)) and len(set(float(x) for x in v)) > 1


def _channel_trend_check(cid, source, paper, rows: list[_Row], models: Sequence[str], param: str,
                         other: str) -> dict:
    """Materials whose ``param`` differs between channels and ``other`` does not: the per-channel
    error is ordered like the per-channel ``param`` (our reading of "errors increase with it")."""
    sel = [r for r in rows if _chromatic(r.params.get(param)) and not _chromatic(r.params.get(other))]
    outcomes = []
    for r in sel:
        order = np.argsort(r.params[param], kind="stable")
        for model in models:
            if model not in r.errors:
                continue
            e = np.array(r.errors[model]["internal"]["rmse"])
            ok = bool(np.all(np.diff(e[order]) > 0))
            outcomes.append((ok, False, f"{r.name} {model}: {PARAM_LABELS[param]} = {_fmt_value(r.params[param])}, "
                                        f"RMSE R G B = {' '.join(f'{x:.3g}' for x in e)}" + ("" if ok else "  (no)")))
    test = (f"materials with a chromatic {PARAM_LABELS[param]} and an achromatic {PARAM_LABELS[other]}: the "
            f"per-channel internal RMSE increases with the per-channel {PARAM_LABELS[param]} (our reading), "
            f"per (material, model)")
    return _check(cid, source, paper, test, models, outcomes, _missing(sel, models), len(sel))


def _blue_vs_luminance_check(cid, source, paper, rows: list[_Row], model: str) -> dict:
    sel = [r for r in rows if _chromatic(r.params.get("tau"))]
    outcomes = []
    for r in sel:
        if model not in r.errors:
            continue
        e = r.errors[model]["internal"]
        ok = e["rmse"][2] < e["rmse_luminance"]
        outcomes.append((ok, False, f"{r.name}: blue {e['rmse'][2]:.3g}, luminance {e['rmse_luminance']:.3g}"
                         + ("" if ok else "  (no)")))
    return _check(cid, source, paper, f"{model}, slabs with a chromatic τ: RMSE of the blue channel < RMSE of the "
                                      f"luminance, per material", [model], outcomes, _missing(sel, [model]), len(sel))


def reproduction_checks(results: list[MaterialResult]) -> list[dict]:
    """Each finding of Bati 2019 section 4.2 / figure 4 (and the error statements of 5.1-5.2)
    computed from our errors, with a verdict by :data:`HOLDS_AT` / :data:`PARTLY_AT`."""
    rows = [_Row(r.material.name, r.material.category, r.material.params, r.evaluation["models"]) for r in results]
    plastics = [r for r in rows if r.category == "plastic"]
    metals = [r for r in rows if r.category == "metal"]
    slabs = [r for r in rows if r.category == "slab"]

    def metal(a1=None, a0=None):
        return [r for r in metals if (a1 is None or _close(r.params.get("alpha1"), a1))
                and (a0 is None or any(_close(r.params.get("alpha0"), x) for x in np.atleast_1d(a0)))]

    belcour = (B_FWD, B_SYM)
    return [
        _order_check("plastic-ww09-vs-elek", "Fig. 4(a) caption; Sec. 4.2 Plastics",
                     "For plastics, Weidlich and Wilkie's model is consistently more accurate than Elek's.",
                     plastics, [(WW09,), (ELEK,)]),
        _channel_trend_check("plastic-rho", "Sec. 4.2 Plastics",
                             "The errors of both models increase when ρ increases.", plastics, (WW09, ELEK),
                             "rho", "tau"),
        _channel_trend_check("plastic-tau", "Sec. 4.2 Plastics",
                             "The errors of both models increase when τ increases.", plastics, (WW09, ELEK),
                             "tau", "rho"),
        _order_check("plastic-ww-bati19", "Fig. 4 caption; Sec. 5.1",
                     "Bati's corrected Weidlich-Wilkie (eq. 5) has a consistently smaller error on plastics.",
                     plastics, [(WW_BATI,), (WW09, ELEK)]),
        _order_check("metal-belcour-best", "Sec. 4.2 Metals",
                     "On internal paths Belcour's variants clearly produce the smallest RMSE on metals.",
                     metals, [belcour, (WW09, ELEK)]),
        _order_check("metal-elek-vs-ww09", "Sec. 4.2 Metals",
                     "On metals, Elek's model is more accurate than Weidlich and Wilkie's.", metals, [(ELEK,), (WW09,)]),
        _order_check("metal-a1-0.2-ranking", "Fig. 4(b) caption",
                     "Metals with α1 = 0.2: Belcour's models give the best results, followed by Elek's, then "
                     "Weidlich and Wilkie's.", metal(a1=0.2), [belcour, (ELEK,), (WW09,)]),
        _ratio_check("metal-belcour-fwd-sym-similar", "Fig. 4(b) caption; Sec. 5.2",
                     "Belcour's forward and symmetric variants have similar errors on internal paths.",
                     metals, (B_FWD,), (B_SYM,), SIMILAR_RATIO, symmetric=True),
        _ratio_check("metal-a1-0.001-a0-0.05-elek-close", "Fig. 4(b) caption",
                     "Metals with α1 = 0.001, α0 = 0.05: Elek's errors are close to Belcour's.",
                     metal(a1=0.001, a0=0.05), (ELEK,), belcour, CLOSE_RATIO, symmetric=False),
        _ratio_check("metal-a1-0.001-a0-0.2-elek-same", "Fig. 4(b) caption; Sec. 4.2 Metals",
                     "Metals with α1 = 0.001, α0 = 0.2: Elek's errors are indistinguishable from Belcour's.",
                     metal(a1=0.001, a0=0.2), (ELEK,), belcour, INDISTINGUISHABLE_RATIO, symmetric=True),
        _order_check("metal-a1-0.2-ww-bati19", "Fig. 4 caption; Sec. 5.1",
                     "Eq. 5 yields smaller errors than the other Weidlich-Wilkie variants on metallic paints and "
                     "patinas (α1 = 0.2).", metal(a1=0.2), [(WW_BATI,), (WW09, ELEK)]),
        _order_check("metal-a1-0.001-a0-0.001-ww-bati19", "Sec. 5.1",
                     "Frosted metals (α1 = 0.001): eq. 5 beats Elek's when α0 = 0.001 ...",
                     metal(a1=0.001, a0=0.001), [(WW_BATI,), (ELEK,)]),
        _order_check("metal-a1-0.001-rough-ww-bati19", "Sec. 5.1",
                     "... and only then: for α0 = 0.05 and 0.2, Elek's is not worse than eq. 5.",
                     metal(a1=0.001, a0=(0.05, 0.2)), [(ELEK,), (WW_BATI,)]),
        _identical_check("metal-belcour-bati19-internal", "Sec. 5.2",
                         "Errors of eq. 6 on internal paths are identical to Belcour's forward model.",
                         metals, B_BATI, B_FWD),
        _order_check("metal-belcour-bati19-total", "Fig. 10 caption; Sec. 5.2",
                     "Eq. 6 (exact top lobe) systematically improves Belcour's forward model (total BRDF).",
                     metals, [(B_BATI,), (B_FWD,)], part="total"),
        _order_check("metal-belcour-sym-total", "Sec. 4.2 Metals",
                     "With the top reflection included, Belcour's symmetric variant is slightly more accurate than "
                     "the forward one.", metals, [(B_SYM,), (B_FWD,)], part="total"),
        _trend_check("slab-alpha0", "Fig. 4(c) caption; Sec. 4.2 Slabs",
                     "Slabs: the errors of Belcour's forward model increase with decreasing α0.", slabs, B_BTDF, "alpha0"),
        _trend_check("slab-alpha1", "Fig. 4(c) caption; Sec. 4.2 Slabs",
                     "Slabs: the errors of Belcour's forward model increase with decreasing α1.", slabs, B_BTDF, "alpha1"),
        _blue_vs_luminance_check("slab-blue-vs-luminance", "Sec. 4.2 Slabs",
                                 "Slabs with a yellow-tinted τ (S1, S3): errors of the blue channel are smaller "
                                 "than those of the luminance.", slabs, B_BTDF),
    ]


def _close(a: Any, b: float) -> bool:
    return isinstance(a, (int, float)) and abs(float(a) - b) <= 1e-9 * max(1.0, abs(b))


def reproduction_markdown(checks: list[dict]) -> str:
    lines = ["# Reproduction of Bati et al. 2019, section 4.2\n",
             f"Each finding of the paper next to what our errors show. Verdict: *holds* if at least "
             f"{HOLDS_AT:.0%} of the comparisons agree, *partly* if at least {PARTLY_AT:.0%}, else *does not hold*; "
             f"thresholds and ratios (similar <= {SIMILAR_RATIO}, close <= {CLOSE_RATIO}, indistinguishable <= "
             f"{INDISTINGUISHABLE_RATIO}) were fixed before looking at the data. *noise-limited*: comparisons whose "
             f"error difference is below the reference noise floor.\n",
             "| finding (paper) | source | our test | agree | verdict | note |", "|---|---|---|---|---|---|"]
    for c in checks:
        agree = f"{c['agree']}/{c['n']}" + (f" ({c['noise_limited']} noise-limited)" if c["noise_limited"] else "")
        lines.append(f"| {c['paper']} | {c['source']} | {c['test']} | {agree} | **{c['verdict']}** | {c['note']} |")
    for c in checks:
        if c["details"]:
            lines.append(f"\n## {c['id']}: {c['verdict']}\n")
            lines.extend(f"- {d}" for d in c["details"])
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------- HTML

def _selectors(results: list[MaterialResult]) -> tuple[dict[str, list[dict]], dict[str, dict[str, str]]]:
    """Per category the parameter selectors (those that vary) and per material its values;
    ``paper_name`` / ``name`` are added when the parameters do not single out a material."""
    sel: dict[str, list[dict]] = {}
    values: dict[str, dict[str, str]] = {}
    by_cat: dict[str, list[MaterialResult]] = {}
    for r in results:
        by_cat.setdefault(r.material.category, []).append(r)
    for cat, res in by_cat.items():
        res = sorted(res, key=lambda r: _sort_key(r.material))
        table = {r.material.name: {k: param_text(r.material.params, k) for k in PARAM_KEYS
                                   if k in r.material.params} for r in res}
        for r in res:
            table[r.material.name]["paper_name"] = r.material.paper_name
            table[r.material.name]["name"] = r.material.name
        keys = [k for k in PARAM_KEYS if len({t.get(k) for t in table.values()}) > 1]
        for extra in ("paper_name", "name"):
            if len({tuple(t.get(k) for k in keys) for t in table.values()}) == len(table):
                break
            keys.append(extra)
        sel[cat] = [{"key": k, "label": PARAM_LABELS[k],
                     "values": list(dict.fromkeys(t[k] for t in table.values() if t.get(k) is not None))}
                    for k in keys]
        for name, t in table.items():
            values[name] = {k: t.get(k) for k in keys}
    return sel, values


def _html_data(results: list[MaterialResult], styles: dict, overview: dict, meta: dict) -> dict:
    sel, values = _selectors(results)
    cats = list(dict.fromkeys(r.material.category for r in results))
    models = registry.catalogue()
    mats = []
    for r in sorted(results, key=lambda r: (cats.index(r.material.category), _sort_key(r.material))):
        m = r.material
        mats.append({"name": m.name, "category": m.category, "paper_name": m.paper_name, "sel": values[m.name],
                     "params": {k: param_text(m.params, k) for k in PARAM_KEYS if k in m.params},
                     "side": r.evaluation["side"], "parametrization": m.parametrization,
                     "resolution": list(m.resolution), "rays": m.rays,
                     "errors": r.evaluation["models"], "skipped": r.evaluation.get("skipped", {}),
                     "approximations": r.evaluation.get("approximations", {}),
                     "failed": r.evaluation.get("failed", {}), **r.figures})
    return {"format": REPORT_FORMAT, "version": REPORT_VERSION, "meta": meta, "categories": cats,
            "selectors": sel, "materials": mats, "overview": overview,
            "models": {n: {**styles[n], "description": getattr(models.get(n), "description", "")} for n in styles}}


def _script_json(obj: Any) -> str:
    text = json.dumps(obj, separators=(",", ":"), allow_nan=False)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def _esc(x: Any) -> str:
    return html.escape(str(x), quote=True)


def _reproduction_html(checks: list[dict]) -> str:
    rows = []
    for c in checks:
        agree = f"{c['agree']}/{c['n']}" if c["n"] else "–"
        if c["noise_limited"]:
            agree += f"<br><small>{c['noise_limited']} noise-limited</small>"
        details = ""
        if c["details"]:
            items = "".join(f"<li>{_esc(d)}</li>" for d in c["details"])
            details = f"<details><summary>{len(c['details'])} comparison(s)</summary><ul>{items}</ul></details>"
        rows.append(f"<tr class=\"verdict-{_esc(c['verdict'].replace(' ', '-'))}\" data-check=\"{_esc(c['id'])}\">"
                    f"<td>{_esc(c['paper'])}<br><small>{_esc(c['source'])}</small></td>"
                    f"<td>{_esc(c['test'])}{details}</td><td class=\"num\">{agree}</td>"
                    f"<td class=\"verdict\">{_esc(c['verdict'])}</td><td>{_esc(c['note'])}</td></tr>")
    return ("<table class=\"repro\"><thead><tr><th>finding (paper)</th><th>our test</th><th>agree</th>"
            "<th>verdict</th><th>note</th></tr></thead><tbody>" + "".join(rows) + "</tbody></table>")


def _tables_html(tables: dict[str, dict[str, str]]) -> str:
    items = "".join(f"<li>{_esc(cat)}: <a href=\"{_esc(t['md'])}\">Markdown</a> · <a href=\"{_esc(t['csv'])}\">CSV</a></li>"
                    for cat, t in tables.items())
    return f"<ul>{items}<li>all records: <a href=\"errors.json\">errors.json</a></li></ul>"


def _overview_html(overview: dict[str, str]) -> str:
    figs = "".join(f"<figure class=\"overview\" data-category=\"{_esc(cat)}\"><img src=\"{_esc(src)}\" "
                   f"alt=\"errors of the {_esc(cat)} category\" loading=\"lazy\"></figure>"
                   for cat, src in overview.items() if cat != "_all")
    link = (f"<p class=\"hint\">All categories in one figure: <a href=\"{_esc(overview['_all'])}\">"
            f"{_esc(overview['_all'])}</a></p>") if "_all" in overview else ""
    return figs + link


def _asset(name: str) -> str:
    try:
        return (ASSETS / name).read_text(encoding="utf-8")
    except OSError as e:
        raise ReportError(f"{ASSETS / name}: report asset missing ({e.strerror or e})") from None


def render_html(data: dict, checks: list[dict], tables: dict, summary_lines: list[str]) -> str:
    """The static page: template + inlined CSS/JS + embedded data + static sections."""
    page = _asset("index.html")
    meta = data["meta"]
    subs = {
        "<!--TITLE-->": _esc(f"{meta['database']} — layered model errors"),
        "/*CSS*/": _asset("report.css"),
        "/*JS*/": _asset("report.js"),
        "<!--DATA-->": _script_json(data),
        "<!--SUMMARY-->": "".join(f"<li>{_esc(s)}</li>" for s in summary_lines),
        "<!--REPRODUCTION-->": _reproduction_html(checks),
        "<!--OVERVIEW-->": _overview_html(data["overview"]),
        "<!--TABLES-->": _tables_html(tables),
        "<!--THRESHOLDS-->": _esc(f"holds: ≥ {HOLDS_AT:.0%} of the comparisons agree; partly: ≥ {PARTLY_AT:.0%}; "
                                  f"similar: ratio ≤ {SIMILAR_RATIO}; close: ≤ {CLOSE_RATIO}; indistinguishable: ≤ "
                                  f"{INDISTINGUISHABLE_RATIO}; identical: relative difference ≤ {IDENTICAL_REL:g}"),
    }
    data_key = "<!--DATA-->"
    for k, v in [*((k, v) for k, v in subs.items() if k != data_key), (data_key, subs[data_key])]:
        if k not in page:
            raise ReportError(f"{ASSETS / 'index.html'}: placeholder {k} missing")
        page = page.replace(k, v) if k != data_key else page.replace(k, v, 1)   # the data goes in last
    return page


# ---------------------------------------------------------------------- orchestration

def _material_result(mat: ReportMaterial, out: Path, models: Sequence[str] | None, subcells: int, code: str,
                     isotropize: str | None = None) -> tuple[MaterialResult, SimulationResult | None]:
    """Cached or fresh evaluation of one material (and the reference if it had to be read)."""
    json_path, h5_path = _cache_paths(out, mat.name)
    cached = _read_json(json_path)
    ok_cache = cached is not None and cached.get("format") == CACHE_FORMAT and cached.get("version") == CACHE_VERSION
    digest = _reference_digest(mat.path, cached.get("reference") if ok_cache else None)
    key = _evaluation_key(digest["sha256"], code, subcells, models, isotropize)
    if ok_cache and cached.get("key") == key and _slices_key(h5_path) == key:
        return MaterialResult(mat, cached["evaluation"], key, None, True), None
    ref = _read_reference(mat.path)
    t0 = time.perf_counter()
    evaluation, slices = run_evaluation(ref, models, subcells, isotropize)
    entry = {"format": CACHE_FORMAT, "version": CACHE_VERSION, "key": key, "reference": digest,
             "reference_path": str(mat.path), "evaluation": evaluation, "subcells": subcells,
             "elapsed_s": time.perf_counter() - t0}
    _save_cache(json_path, h5_path, entry, slices)
    return MaterialResult(mat, evaluation, key, slices, False), ref


def _figures(res: MaterialResult, ref: SimulationResult | None, out: Path, styles: dict,
             incidents: Sequence[float] | None, report_key: str) -> bool:
    """Draw the material's figures unless its stamp says they are current; True if drawn."""
    rel_dir = Path("figures") / material_dir(res.material.name)
    fig_dir = out / rel_dir
    style_key = {n: styles[n] for n in res.evaluation["models"]}
    fkey = hashlib.sha256(json.dumps([res.key, report_key, None if incidents is None else sorted(incidents),
                                      style_key], sort_keys=True).encode()).hexdigest()[:20]
    stamp_path = fig_dir / "stamp.json"
    stamp = _read_json(stamp_path)
    if stamp and stamp.get("key") == fkey and _files_exist(out, stamp.get("figures", {})):
        res.figures = stamp["figures"]
        return False
    if ref is None:
        ref = _read_reference(res.material.path)
    if res.slices is None:
        res.slices = _load_slices(_cache_paths(out, res.material.name)[1], res.key, res.evaluation["models"])
        if res.slices is None:
            raise ReportError(f"{_cache_paths(out, res.material.name)[1]}: unreadable cache; delete it and rerun")
    fig_dir.mkdir(parents=True, exist_ok=True)
    res.figures = draw_material_figures(ref, res.slices, fig_dir, rel_dir.as_posix(), styles, incidents)
    _atomic_json(stamp_path, {"key": fkey, "figures": res.figures})
    return True


def _files_exist(out: Path, figures: dict) -> bool:
    paths = [figures.get("energy")]
    for inc in figures.get("incidents", []):
        paths += [inc.get("plane"), inc.get("orders"), *inc.get("top", {}).values()]
    return all(p and (out / p).is_file() for p in paths)


def build_report(results_dir: str | Path, out_dir: str | Path, *, models: Sequence[str] | None = None,
                 subcells: int = 5, progress: Progress | None = None,
                 incidents_for_figures: Sequence[float] | None = None,
                 definition: str | Path | None = None, fits: bool = False,
                 isotropize: str | None = None) -> ReportSummary:
    """Evaluate every finished material of ``results_dir`` and write the report into ``out_dir``.

    ``models``: model names (default: every model of the registry that applies to each
    material); ``subcells``: sub-cells per cell axis for the model integration;
    ``progress(done, total, message)``: called once per material, after it is done;
    ``incidents_for_figures``: incident elevations (degrees) to draw figures for (default all;
    errors always use every incident); ``definition``: the database definition when the one named
    in the manifest has moved; ``fits``: also fit the compact models (hp15-fit, ggx1-fit,
    ggx2-fit) to every BRDF (seconds to minutes each); ``isotropize="mean"``: let isotropic models
    evaluate anisotropic stacks with the mean roughness (noted per material). Raises
    :class:`ReportError` on bad input.
    """
    if fits:
        models = list(dict.fromkeys([*(models or registry.all_models()), *registry.FITTED]))
    t0 = time.perf_counter()
    rd, out = Path(results_dir), Path(out_dir)
    if rd.exists() and out.exists() and rd.resolve() == out.resolve():
        raise ReportError(f"{out}: the report must go to its own directory, not the results directory itself")
    if out.exists() and not out.is_dir():
        raise ReportError(f"{out}: exists and is not a directory")
    if subcells < 1:
        raise ReportError(f"subcells = {subcells}: must be >= 1")
    if models is not None:
        known = registry.catalogue()
        unknown = [n for n in models if n not in known]
        if unknown:
            raise ReportError(f"unknown model {unknown[0]!r} (known: {', '.join(known)})")
        models = list(dict.fromkeys(models))
    manifest, materials, missing, warnings = open_results(rd, definition, exclude=out)
    out.mkdir(parents=True, exist_ok=True)
    summary = ReportSummary(out, out / "index.html", out / "errors.json", missing=missing, warnings=list(warnings))
    code, report_key = model_code_key(), report_code_key()
    styles = model_style([*registry.all_models(), *(models or ())])
    results: list[MaterialResult] = []
    for k, mat in enumerate(materials):
        t1 = time.perf_counter()
        res, ref = _material_result(mat, out, models, subcells, code, isotropize)
        t2 = time.perf_counter()
        drawn = _figures(res, ref, out, styles, incidents_for_figures, report_key)
        t3 = time.perf_counter()
        res.slices = None   # free memory: the figures are on disk
        results.append(res)
        summary.materials.append(mat.name)
        (summary.reused if res.from_cache else summary.evaluated).append(mat.name)
        (summary.figures_drawn if drawn else summary.figures_reused).append(mat.name)
        if res.evaluation.get("failed"):
            summary.failed[mat.name] = dict(res.evaluation["failed"])
            summary.warnings.extend(f"{mat.name}: {n} failed: {msg}" for n, msg in res.evaluation["failed"].items())
        if progress is not None:
            n_models = len(res.evaluation["models"])
            ev = "from cache" if res.from_cache else f"evaluated in {t2 - t1:.1f} s"
            fg = f"drawn in {t3 - t2:.1f} s" if drawn else "up to date"
            progress(k + 1, len(materials), f"{mat.name}: {n_models} model(s) {ev}; figures {fg}")
    if incidents_for_figures is not None:
        drawn_at = {i["theta"] for r in results for i in r.figures.get("incidents", [])}
        unknown_angles = [w for w in incidents_for_figures if not any(abs(w - t) < 1e-6 for t in drawn_at)]
        if unknown_angles:
            summary.warnings.append(f"no material has the incident direction(s) {unknown_angles} asked for figures")
    _write_outputs(results, manifest, out, styles, summary, rd, subcells, code)
    summary.elapsed_s = time.perf_counter() - t0
    return summary


def _write_outputs(results: list[MaterialResult], manifest: dict, out: Path, styles: dict, summary: ReportSummary,
                   rd: Path, subcells: int, code: str) -> None:
    records = error_records(results)
    _atomic_json(out / "errors.json", records)
    summary.records = len(records)
    by_cat: dict[str, list[MaterialResult]] = {}
    for r in results:
        by_cat.setdefault(r.material.category, []).append(r)
    used = {n for r in results for n in r.evaluation["models"]}
    styles = {n: s for n, s in styles.items() if n in used}
    tables, overview = {}, {}
    for cat, res in by_cat.items():
        safe = _safe_part(cat)
        _atomic_text(out / "tables" / f"{safe}.csv", category_csv(res))
        _atomic_text(out / "tables" / f"{safe}.md", category_markdown(cat, res))
        tables[cat] = {"csv": f"tables/{safe}.csv", "md": f"tables/{safe}.md"}
        if any(r.evaluation["models"] for r in res):
            _save_figure(_errors_figure({cat: res}, styles), out / "figures" / f"errors_{safe}.png")
            overview[cat] = f"figures/errors_{safe}.png"
    plotted = {c: r for c, r in by_cat.items() if c in overview}
    if plotted:
        _save_figure(_errors_figure(plotted, styles), out / "figures" / "errors_overview.png")
        overview["_all"] = "figures/errors_overview.png"
    checks = reproduction_checks(results)
    summary.reproduction = checks
    _atomic_json(out / "reproduction.json", checks)
    _atomic_text(out / "reproduction.md", reproduction_markdown(checks))
    meta = {"database": manifest.get("database", rd.name), "quality": manifest.get("quality"),
            "rays_per_slice": manifest.get("rays_per_slice"), "results_dir": os.path.relpath(rd, out),
            "subcells": subcells, "model_code": code,
            "generated": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
            "materials": len(results), "missing": summary.missing, "warnings": summary.warnings}
    data = _html_data(results, styles, overview, meta)
    lines = [f"database {meta['database']}, quality {meta['quality']} ({meta['rays_per_slice']:,} rays per slice)"
             if isinstance(meta["rays_per_slice"], int) else f"database {meta['database']}",
             f"{len(results)} material(s), {len(records)} (material, model) errors, models integrated with "
             f"{subcells}×{subcells} sub-cells per cell; model code {code}",
             f"generated {meta['generated']}"]
    if summary.missing:
        lines.append(f"{len(summary.missing)} material(s) of the definition not simulated yet: "
                     + ", ".join(summary.missing[:8]) + (" …" if len(summary.missing) > 8 else ""))
    lines += [f"warning: {w}" for w in summary.warnings]
    _atomic_text(out / "index.html", render_html(data, checks, tables, lines))
