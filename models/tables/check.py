"""Show, build and check the models' precomputed tables (:func:`check_tables`: what ``gonio tables`` runs).

The tables are the Belcour FGD/TIR tables (:mod:`models.tables.belcour`, one pair per masking model) and
the multilayer-lut mean-transmission tables (:mod:`models.tables.multilayer`). Each lives in the
cache directory (``$GONIOMETER_CACHE``, default ``~/.cache/goniometer``) with a version stamp; the
models build a missing or stale one on first use, :func:`check_tables` does it ahead of time
(``rebuild=True`` rebuilds current ones too) and, with ``check_points=N``, compares N random off-grid
lookups with the quadrature itself in the regions where each module states an error bound
(:data:`FGD_BOUND`, :data:`TIR_BOUND`, the ``ERROR_*`` bounds of :mod:`models.tables.multilayer`). A
:class:`Check` is ``ok`` when its largest error is within its bound. ``docs/tables.md``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from models.tables import belcour as tables
from models.tables import multilayer as multilayer_tables

MASKINGS = ("separable", "height-correlated")

#: stated bound of the Belcour 4D FGD table where Fresnel has no critical angle (mu >= 0.05)
FGD_BOUND = tables.FGD_ERROR
#: TIR lookups are compared with the table's own quadrature at the point, which errs by up to
#: ``tables.TIR_ERROR`` as the table does (the indicator quadrature is not smooth between nodes):
#: their difference is bounded by twice the stated error
TIR_BOUND = 2 * tables.TIR_ERROR


@dataclass
class Check:
    """One table check: the largest absolute lookup error over ``points`` random points of ``region``."""

    quantity: str
    region: str
    points: int
    max_error: float
    bound: float

    @property
    def ok(self) -> bool:
        return bool(self.max_error <= self.bound)


@dataclass
class TableEntry:
    """One table file: ``status`` is "current", "stale" (other version/grid, unreadable) or "missing"."""

    name: str
    path: str
    status: str
    bytes: int = 0
    built: bool = False
    checks: list[Check] = field(default_factory=list)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["checks"] = [dict(asdict(c), ok=c.ok) for c in self.checks]
        return d


@dataclass(frozen=True)
class _TableSet:
    """Files built together by one ``build`` call and read by one ``current`` test."""

    names: tuple[str, ...]
    paths: tuple[Path, ...]
    current: Callable[[], bool]
    build: Callable[[Callable[[str, float], None] | None], object]
    check: Callable[[int, np.random.Generator], list[tuple[int, Check]]]  # (file index, check)


def _status(path: Path, current: bool) -> str:
    if current:
        return "current"
    return "stale" if path.exists() else "missing"


def _belcour_set(cache_dir: Path, masking: str) -> _TableSet:
    hc = masking == "height-correlated"
    paths = tables.table_paths(cache_dir, hc)

    def current() -> bool:
        return (tables.read_if_current(paths["fgd"], hc, ("fgd",)) is not None
                and tables.read_if_current(paths["tir"], hc, ("tir",)) is not None)

    def check(n: int, rng: np.random.Generator) -> list[tuple[int, Check]]:
        t = tables.load_belcour_tables(cache_dir, hc)
        mu = 0.05 + 0.95 * rng.random(n)
        alpha = rng.random(n) ** 2
        eta = 1.2 + 2.8 * rng.random(n)
        kappa = np.where(rng.random(n) < 0.5, 0.0, 8.0 * rng.random(n))
        err = [abs(float(t.fgd_at(m, a, e, k)) - tables.fgd_direct(m, a, e, k, hc))
               for m, a, e, k in zip(mu, alpha, eta, kappa)]
        mu_t = 0.05 + 0.95 * rng.random(n)
        alpha_t = 0.1 + 0.9 * rng.random(n)
        eta_up = rng.random(n)
        err_t = [abs(float(t.tir_at(m, a, e)) - tables.tir_direct(m, a, e, hc))
                 for m, a, e in zip(mu_t, alpha_t, eta_up)]
        return [(0, Check("FGD (4D table)", "eta >= 1.2, mu >= 0.05", n, float(max(err)), FGD_BOUND)),
                (1, Check("TIR", "alpha >= 0.1, mu >= 0.05", n, float(max(err_t)), TIR_BOUND))]

    return _TableSet((f"belcour-fgd-{masking}", f"belcour-tir-{masking}"), (paths["fgd"], paths["tir"]), current,
                     lambda progress: tables.build_belcour_tables(cache_dir, progress, hc), check)


def _multilayer_set(cache_dir: Path) -> _TableSet:
    path = multilayer_tables.table_path(cache_dir)
    mt = multilayer_tables

    def check(n: int, rng: np.random.Generator) -> list[tuple[int, Check]]:
        t = mt.load_multilayer_tables(cache_dir)
        mu = 0.1 + 0.9 * rng.random(n) ** 1.5
        alpha = rng.random(n) ** 2
        eta = 1.02 + (mt.ETA_MAX - 1.02) * rng.random(n)
        T, C = t.at(mu, alpha, eta)
        ref = mt.direct(mu, alpha, eta)
        return [(0, Check("T (mean transmission)", "eta >= 1.02, mu >= 0.1", n,
                          float(np.abs(T - ref[:, 0]).max()), mt.ERROR_T_UP)),
                (0, Check("T |dC| (mean refracted cosine)", "eta >= 1.02, mu >= 0.1", n,
                          float((ref[:, 0] * np.abs(C - ref[:, 1])).max()), mt.ERROR_TC))]

    return _TableSet(("multilayer-lut",), (path,), lambda: mt.read_if_current(path) is not None,
                     lambda progress: mt.build_multilayer_tables(cache_dir, progress), check)


def table_sets(cache_dir: Path, maskings: tuple[str, ...] = ("separable",)) -> list[_TableSet]:
    """The table sets of the Belcour models (one per masking) and of multilayer-lut."""
    return [_belcour_set(cache_dir, m) for m in maskings] + [_multilayer_set(cache_dir)]


def check_tables(cache_dir: Path, maskings: tuple[str, ...] = ("separable",), build: bool = True, rebuild: bool = False,
        check_points: int = 0, seed: int = 1,
        progress: Callable[[str], Callable[[str, float], None] | None] | None = None) -> list[TableEntry]:
    """Status of every table; build missing/stale ones (``build``) or all (``rebuild``); check them.

    ``progress(name)`` may return a ``(stage, fraction)`` callback used while ``name`` is built.
    """
    for m in maskings:
        if m not in MASKINGS:
            raise ValueError(f"masking: {m!r} is not one of {', '.join(MASKINGS)}")
    if check_points < 0:
        raise ValueError(f"check points: must be >= 0, got {check_points}")
    rng = np.random.default_rng(seed)
    entries: list[TableEntry] = []
    for ts in table_sets(cache_dir, maskings):
        cur = ts.current()
        group = [TableEntry(n, str(p), _status(p, cur)) for n, p in zip(ts.names, ts.paths)]
        if rebuild or (build and not cur):
            ts.build(progress(ts.names[0]) if progress else None)
            if not ts.current():
                raise OSError(f"{', '.join(ts.names)}: built but not readable in {cache_dir}")
            for e in group:
                e.built, e.status = True, "current"
        for e, p in zip(group, ts.paths):
            e.bytes = p.stat().st_size if p.exists() else 0
        if check_points and group[0].status == "current":
            for i, c in ts.check(check_points, rng):
                group[i].checks.append(c)
        entries += group
    return entries
