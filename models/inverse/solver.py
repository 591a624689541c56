"""Algorithm 2 of Bati 2021: lobes (top first) -> a physical layered material.

:func:`solve` inverts the lobes top-down, each in the context of the layers chosen above it,
returning an :class:`Inversion` (stack, per-lobe classes and chosen points; never raises for an
unachievable request); :func:`invert` returns the :class:`goniometer.stack.Stack` or raises
:class:`~models.inverse.lobes.NotAchievable`; :func:`equivalence_classes` the classes.
Default picks of upper lobes are searched when they leave a lower lobe unachievable (choice 6
of ``docs/inverse.md``). :func:`bench_invert` times figure 17.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Sequence

import numpy as np

from goniometer.stack import Interface, Medium, Stack
from models.inverse.classes import Layer, LobeClass, LobeSolution
from models.inverse.context import Context
from models.inverse.lobes import (ETA_MAX_DEFAULT, InverseError, InverseOptions, Lobe, NotAchievable, Pick,
                                  PickError, as_pick, jsonable)
from models.inverse.one_layer import conductor_class, one_layer_dielectric_class
from models.inverse.two_layer import two_layer_class


# ============================================================================ dispatch

def lobe_class(lobe: Lobe, context: Context | None = None, conductor: bool = False, tau0: Any = None,
               diagnose: bool = True) -> LobeClass:
    """The equivalence class of ``lobe`` below ``context`` (air by default): 1-layer dielectric or
    conductor (section 5.1), 2-layer dielectric or over a conductor base (section 5.2)."""
    if lobe.layers == 1:
        if conductor:
            return conductor_class(lobe, context, tau0)
        if tau0 is not None:
            raise InverseError("tau0: for a 1-layer dielectric lobe tau0 follows from eta1 (choose eta1 or u1)")
        return one_layer_dielectric_class(lobe, context)
    return two_layer_class(lobe, context, conductor, tau0, diagnose)


# ============================================================================ stacking (alg. 2)

@dataclass
class Inversion:
    """Result of :func:`solve`: the stack (if achievable), per-lobe classes and solutions."""

    lobes: list[Lobe]
    base: str
    options: InverseOptions
    achievable: bool
    reason: str | None
    failed_lobe: int
    classes: list[LobeClass]
    solutions: list[LobeSolution]
    searched: bool = False
    elapsed_s: float = 0.0
    name: str = "inverse"

    @property
    def layers(self) -> list[Layer]:
        return [layer for s in self.solutions for layer in s.layers]

    @property
    def lobe_interfaces(self) -> list[list[int]]:
        """Interface indices (top = 0) belonging to each lobe."""
        out, k = [], 0
        for s in self.solutions:
            out.append(list(range(k, k + len(s.layers))))
            k += len(s.layers)
        return out

    def stack(self, name: str | None = None) -> Stack:
        if not self.achievable:
            raise NotAchievable(self.reason or "not achievable", self.failed_lobe)
        return layers_to_stack(self.layers, name or self.name)

    def predicted(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The inverse's own prediction of each lobe: (energy RGB, variance RGB)."""
        return [(s.energy, s.variance) for s in self.solutions]

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"base": self.base, "achievable": self.achievable, "eta_max": self.options.eta_max,
                             "lobes": []}
        if not self.achievable:
            d["reason"] = self.reason
            d["failed_lobe"] = self.failed_lobe
        for k, lobe in enumerate(self.lobes):
            e: dict[str, Any] = {"R": list(lobe.R), "sigma": lobe.sigma, "layers": lobe.layers}
            if k < len(self.classes):
                e["class"] = self.classes[k].summary()
            if k < len(self.solutions):
                s = self.solutions[k]
                e["choices"] = jsonable(s.choices)
                e["layers_retrieved"] = [layer.to_dict() for layer in s.layers]
                e["info"] = jsonable(s.info)
            d["lobes"].append(e)
        return d


def layers_to_stack(layers: Sequence[Layer], name: str = "inverse") -> Stack:
    """The material (goniometer Stack) of the paper's layer list: a medium wherever ``tau > 0``
    (never above the first interface), then the interface. Category: metal (conductor base), slab
    (dielectric ending in air, eta = 1), other."""
    out: list[Any] = []
    for i, layer in enumerate(layers):
        if i > 0 and np.any(layer.tau > 0.0):
            out.append(Medium(tuple(float(x) for x in layer.tau)))
        if layer.conductor:
            out.append(Interface(float(layer.alpha), tuple(float(x) for x in layer.eta),
                                 tuple(float(x) for x in layer.kappa)))
        else:
            out.append(Interface(float(layer.alpha), (float(layer.eta[0]),) * 3))
    last = layers[-1]
    category = "metal" if last.conductor else ("slab" if float(last.eta[0]) == 1.0 else "other")
    return Stack(name, tuple(out), category)


def _check_lobes(lobes: Sequence[Lobe], base: str) -> list[Lobe]:
    if base not in ("dielectric", "conductor"):
        raise InverseError(f"base: {base!r} is not one of dielectric, conductor")
    out = []
    for k, lobe in enumerate(lobes):
        if not isinstance(lobe, Lobe):
            raise InverseError(f"lobe {k + 1}: expected a models.inverse.solver.Lobe, got {type(lobe).__name__}")
        out.append(lobe)
    if not out:
        raise InverseError("at least one lobe is required")
    return out


#: candidate positions tried when a default choice of an upper lobe leaves a lower lobe unachievable
SEARCH_POSITIONS = (0.5, 0.25, 0.75, 0.1, 0.9, 0.02, 0.98, 0.0, 1.0)


@lru_cache(maxsize=None)
def _candidate_table(kind: str, absorbing: bool) -> tuple[Pick, ...]:
    if kind == "conductor-1":
        return tuple(Pick(u1=u) for u in SEARCH_POSITIONS)
    if kind == "dielectric-1":
        cands = [Pick()]
        for root in ("upper", "lower"):
            for u in (0.0, 0.1, 0.3, 0.6, 1.0) if absorbing else (0.0,):
                cands.append(Pick(root=root, u1=u))
        return tuple(cands)
    cands = [Pick(u1=u1, u2=u2) for u1 in SEARCH_POSITIONS for u2 in SEARCH_POSITIONS]
    cands.sort(key=lambda p: (abs(p.u1 - 0.5) + abs(p.u2 - 0.5)))
    return tuple(cands)


def _candidates(lobe: Lobe, conductor: bool, pick: Pick, absorbing: bool) -> tuple[Pick, ...]:
    """Picks to try for a lobe whose pick is the default (choice 6 search), default first."""
    if not pick.is_default:
        return (pick,)
    kind = ("conductor-" if conductor else "dielectric-") + str(lobe.layers)
    return _candidate_table(kind, absorbing)


def solve(lobes: Sequence[Lobe], base: str = "dielectric", picks: Sequence[Pick | dict | None] | None = None,
          options: InverseOptions | None = None, search: bool = True, name: str = "inverse",
          max_search: int = 2000) -> Inversion:
    """Algorithm 2: invert the lobes top-down (the top lobe first) and return an :class:`Inversion`.

    ``base``: ``"dielectric"`` (the last interface transmits into a semi-infinite dielectric) or
    ``"conductor"`` (the last lobe's last interface is a conductor). ``picks``: one
    :class:`Pick` (or dict, or None) per lobe. With ``search`` (default), default picks of upper
    lobes are moved when they leave a lower lobe unachievable (choice 6). Never raises for an
    unachievable request: ``achievable`` is False and ``reason`` says why (raises
    :class:`InverseError` only for malformed input).
    """
    t_start = time.perf_counter()
    lobes = _check_lobes(lobes, base)
    o = options if options is not None else InverseOptions()
    K = len(lobes)
    if picks is None:
        picks = [None] * K
    if len(picks) != K:
        raise InverseError(f"picks: expected {K} (one per lobe), got {len(picks)}")
    pk = [as_pick(p) for p in picks]
    # a quick pass (N1 scans of n_scan samples); if it fails, one pass with the fine fallback scans
    for fine in (False, True):
        result, failures = _solve_pass(lobes, base, pk, o, search, max_search, fine)
        if result is not None:
            classes, sols = result
            return Inversion(list(lobes), base, o, True, None, 0, classes, sols, searched=_was_searched(sols, pk),
                             elapsed_s=time.perf_counter() - t_start, name=name)
    # report the failure along the default path (the first recorded), with its diagnosis
    k, reason, classes, sols = failures[0] if failures else (0, "no solution", [], [])
    if classes and not classes[-1].achievable and classes[-1].lobe.layers == 2 and not reason.startswith("pick"):
        c = classes[-1]
        c = two_layer_class(c.lobe, c.context, c.conductor, c.tau0, diagnose=True)
        classes = classes[:-1] + [c]
        reason = c.reason or reason
    deeper = max(failures, key=lambda f: f[0]) if failures else None
    if deeper is not None and deeper[0] > k:
        reason += (f" (searching the classes of the lobes above, the furthest reached was lobe {deeper[0] + 1}: "
                   f"{deeper[1]})")
    return Inversion(list(lobes), base, o, False, f"lobe {k + 1} ({lobes[k].describe()}): {reason}", k + 1,
                     classes, sols, elapsed_s=time.perf_counter() - t_start, name=name)


def _solve_pass(lobes: list[Lobe], base: str, pk: list[Pick], o: InverseOptions, search: bool, max_search: int,
                fine: bool):
    """One depth-first pass of alg. 2 with the choice-6 search; returns ((classes, solutions) or None,
    failures as (lobe index, reason, classes, solutions))."""
    K = len(lobes)
    budget = [max_search]
    failures: list[tuple[int, str, list[LobeClass], list[LobeSolution]]] = []

    def rec(k: int, ctx: Context, classes: list[LobeClass], sols: list[LobeSolution]):
        if k == K:
            return classes, sols
        conductor = base == "conductor" and k == K - 1
        lobe = lobes[k]
        p = pk[k]
        tau0 = p.tau0 if (lobe.layers == 2 or conductor) else None
        try:
            if lobe.layers == 2:
                cls = two_layer_class(lobe, ctx, conductor, tau0, diagnose=False, fine=fine)
            else:
                cls = lobe_class(lobe, ctx, conductor, tau0)
        except InverseError as e:
            raise InverseError(f"lobe {k + 1}: {e}") from None
        if not cls.achievable:
            failures.append((k, cls.reason or "", classes + [cls], sols))
            return None
        cands = _candidates(lobe, conductor, p, ctx.absorbing) if (search and k < K - 1) else (p,)
        for cand in cands:
            if budget[0] <= 0:
                break
            budget[0] -= 1
            try:
                sol = cls.pick(cand)
            except PickError as e:
                if cand is p:
                    failures.append((k, f"pick: {e}", classes + [cls], sols))
                    if not p.is_default:
                        return None
                continue
            r = rec(k + 1, sol.context, classes + [cls], sols + [sol])
            if r is not None:
                return r
        return None

    root_ctx = Context.ambient(1.0, absorbing=False, options=o)
    return rec(0, root_ctx, [], []), failures


def _was_searched(sols: list[LobeSolution], picks: list[Pick]) -> bool:
    """True if some default pick was moved away from its default by the search."""
    for s, p in zip(sols, picks):
        if not p.is_default:
            continue
        u1 = s.choices.get("u1")
        u2 = s.choices.get("u2")
        if "root" in s.choices:  # 1-layer dielectric: default u1 = 0
            if u1 is not None and abs(float(u1)) > 1e-9:
                return True
            continue
        for u in (u1, u2):
            if u is None:
                continue
            if np.any(np.abs(np.atleast_1d(np.asarray(u, dtype=float)) - 0.5) > 1e-6):
                return True
    return False


def _choices_to_picks(lobes: Sequence[Lobe], picks: Any, choices: dict[str, Any]) -> list[Pick | dict | None]:
    K = len(lobes)
    out: list[Any] = list(picks) if picks is not None else [None] * K
    if len(out) != K:
        raise InverseError(f"picks: expected {K} (one per lobe), got {len(out)}")
    for key, value in choices.items():
        m = re.fullmatch(r"lobe(\d+)", key)
        if not m:
            raise InverseError(f"unknown choice {key!r}: use lobe1=Pick(...) (or a dict), lobe2=..., or picks=[...]")
        k = int(m.group(1))
        if not 1 <= k <= K:
            raise InverseError(f"{key}: there are {K} lobes")
        if out[k - 1] is not None:
            raise InverseError(f"{key}: given twice")
        out[k - 1] = value
    return out


def invert(lobes: Sequence[Lobe], base: str = "dielectric", *, picks: Sequence[Pick | dict | None] | None = None,
           eta_max: float = ETA_MAX_DEFAULT, options: InverseOptions | None = None, name: str = "inverse",
           search: bool = True, **choices: Any) -> Stack:
    """Lobes (top first) -> a physical :class:`goniometer.stack.Stack` (algorithm 2).

    Free choices: ``picks=[Pick|dict|None, ...]`` or ``lobe1=Pick(...)``, ``lobe2={"u1": 0.3}``, ...
    (defaults: class centres, choice 6). Raises :class:`NotAchievable` (with the reason and the
    violated bound) when no physical stack exists, :class:`InverseError` on malformed input.
    """
    o = options if options is not None else InverseOptions(eta_max=eta_max)
    inv = solve(lobes, base, _choices_to_picks(lobes, picks, choices), o, search=search, name=name)
    return inv.stack()


def equivalence_classes(lobes: Sequence[Lobe], base: str = "dielectric",
                        picks: Sequence[Pick | dict | None] | None = None,
                        options: InverseOptions | None = None) -> list[LobeClass]:
    """The class of every lobe, each in the context of the lobes chosen above it (alg. 2); the
    list stops at the first unachievable lobe (whose class says why)."""
    return solve(lobes, base, picks, options).classes


# ============================================================================ benchmark

#: figure 17 (read from the caption): a blue and a red rough 2-layer lobe, blue on top
FIG17_LOBES = (Lobe((0.025, 0.045, 0.05), 0.028, 2), Lobe((0.052, 0.025, 0.025), 0.014, 2))


def bench_invert(repeat: int = 20, lobes: Sequence[Lobe] = FIG17_LOBES, base: str = "dielectric") -> float:
    """Median seconds of one :func:`solve` of ``lobes`` (figure 17 by default) after a warm-up
    call (numba compilation and the FGD kernel load excluded). Single-threaded by construction
    (the inverse runs no parallel kernels)."""
    solve(lobes, base)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        solve(lobes, base)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))
