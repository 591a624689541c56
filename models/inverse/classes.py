"""Equivalence classes and their chosen points: the base types of the inverse method.

A :class:`LobeClass` is the set of layer stacks giving one lobe below a :class:`Context`
(``achievable``/``reason``, JSON-friendly ``bounds``, :meth:`~LobeClass.sample`,
:meth:`~LobeClass.pick`); a pick gives a :class:`LobeSolution`: its :class:`Layer` list (the
paper's stack S, alg. 4), the context below it and the inverse's prediction of its sub-lobes.
The classes themselves: :mod:`models.inverse.one_layer` (section 5.1) and
:mod:`models.inverse.two_layer` (section 5.2); ``docs/inverse.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from models.inverse.context import Context, SubLobe
from models.inverse.lobes import Lobe, NotAchievable, Pick, jsonable


@dataclass(frozen=True)
class Layer:
    """One layer of the paper's stack S (alg. 4): optical depth ``tau`` (RGB) of the medium above
    the interface, its GGX roughness ``alpha``, and the absolute index ``eta + i kappa`` (RGB) of
    the medium below it."""

    tau: np.ndarray
    alpha: float
    eta: np.ndarray
    kappa: np.ndarray

    @property
    def conductor(self) -> bool:
        return bool(np.any(self.kappa > 0.0))

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"tau": self.tau.tolist(), "alpha": self.alpha}
        if self.conductor:
            d["eta"] = self.eta.tolist()
            d["kappa"] = self.kappa.tolist()
        else:
            d["eta"] = float(self.eta[0])
        return d


def inherent_variance_spread(sublobes: Sequence["SubLobe"], sigma: float) -> float:
    """The smallest worst-channel relative variance error any achromatic roughness could give these
    sub-lobes (choice 3): each sub-lobe's forward variance is ``v_c(s) = sigma + slope_c (s - s_c)``
    with slopes ``J (1 + m_c)`` that differ by the small m_c only, so its minimax error is half the
    spread of its channel variances (to a relative O(m)); the lobe's (energy-weighted) error is at
    most the largest over its sub-lobes. 0 for a smooth lobe."""
    if sigma <= 0.0:
        return 0.0
    return max(float(np.ptp(s.variance)) / (2.0 * sigma) for s in sublobes)


@dataclass
class LobeSolution:
    """One chosen point of a lobe's class: its layers, the context below them, the inverse's
    prediction of its sub-lobes (one per interface), and the resolved choices."""

    layers: list[Layer]
    context: Context
    sublobes: list[SubLobe]
    choices: dict[str, Any]
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def energy(self) -> np.ndarray:
        return np.sum([s.energy for s in self.sublobes], axis=0)

    def variance_spread(self, sigma: float) -> float:
        """:func:`inherent_variance_spread` of this lobe's sub-lobes."""
        return inherent_variance_spread(self.sublobes, sigma)

    @property
    def variance(self) -> np.ndarray:
        e = np.array([s.energy for s in self.sublobes])
        v = np.array([s.variance for s in self.sublobes])
        tot = e.sum(axis=0)
        return np.where(tot > 0, (e * v).sum(axis=0) / np.where(tot > 0, tot, 1.0), 0.0)


@dataclass
class LobeClass:
    """Equivalence class of one lobe in a context (base class).

    ``achievable`` and ``reason``; ``bounds`` (name -> intervals or values, JSON-friendly);
    :meth:`sample` returns the sampled class as arrays; :meth:`pick` a :class:`LobeSolution`.
    """

    kind: str
    lobe: Lobe
    context: Context
    achievable: bool
    reason: str | None
    bounds: dict[str, Any]

    def pick(self, pick: Pick | dict | None = None) -> LobeSolution:  # pragma: no cover - abstract
        raise NotImplementedError

    def sample(self, n: int = 64) -> dict[str, np.ndarray]:  # pragma: no cover - abstract
        raise NotImplementedError

    def _require(self) -> None:
        if not self.achievable:
            raise NotAchievable(self.reason or "empty class")

    def summary(self) -> dict[str, Any]:
        return {"kind": self.kind, "achievable": self.achievable, "reason": self.reason,
                "bounds": jsonable(self.bounds)}
