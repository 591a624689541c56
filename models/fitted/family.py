"""A parametric BRDF family of the fitted models (:class:`Family`): parameter layout (:class:`ParamSpec`),
bounds and internal coordinates, evaluation and Jacobian on :class:`models.fitted.samples.Samples`.
Families: :mod:`models.fitted.ggx`, :mod:`models.fitted.hp15`; ``docs/fitted.md``."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.base import ModelError
from models.fitted.samples import Samples

#: 1 / pi (the Lambertian term ``kd / pi``)
INV_PI = 1.0 / math.pi
#: central-difference step of the shape parameters' Jacobian, in internal (mostly log) coordinates
FD_STEP = 1e-4


@dataclass(frozen=True)
class ParamSpec:
    """One named parameter (scalar or RGB) with its bounds and internal coordinate.

    Internal coordinate: ``ln x`` if ``log`` else ``x / scale`` (``scale`` per channel; for a
    scaled parameter ``lower``, ``upper``, ``typical`` and ``start`` are given in units of
    ``scale``). ``typical`` is the (lower, upper) range random starts draw from (log-uniform if
    ``log``); ``start`` the value of start 0.
    """

    name: str
    size: int
    lower: float
    upper: float
    log: bool = False
    scale: tuple[float, ...] | None = None
    typical: tuple[float, float] | None = None
    linear: bool = False  # the model is affine in it: solved linearly before each start
    positive: bool = False  # must be > 0 for the model to be defined (implied by log)
    start: float = 0.0


class Family:
    """A parametric BRDF family: parameter layout, evaluation and Jacobian on :class:`Samples`."""

    kind: str = ""
    specs: tuple[ParamSpec, ...] = ()

    # ------------------------------------------------------------- layout
    @property
    def size(self) -> int:
        return sum(s.size for s in self.specs)

    def slices(self) -> dict[str, slice]:
        out, k = {}, 0
        for s in self.specs:
            out[s.name] = slice(k, k + s.size)
            k += s.size
        return out

    def scale(self, s: ParamSpec) -> np.ndarray:
        return np.ones(s.size) if s.scale is None else np.asarray(s.scale, dtype=float)

    def to_internal(self, x: np.ndarray) -> np.ndarray:
        z = np.empty(self.size)
        for s, sl in zip(self.specs, self.slices().values()):
            z[sl] = np.log(x[sl]) if s.log else x[sl] / self.scale(s)
        return z

    def to_natural(self, z: np.ndarray) -> np.ndarray:
        x = np.empty(self.size)
        for s, sl in zip(self.specs, self.slices().values()):
            x[sl] = np.exp(z[sl]) if s.log else z[sl] * self.scale(s)
        return x

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds in natural coordinates."""
        lo, hi = np.empty(self.size), np.empty(self.size)
        for s, sl in zip(self.specs, self.slices().values()):
            lo[sl], hi[sl] = s.lower * self.scale(s), s.upper * self.scale(s)
        return lo, hi

    def internal_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.bounds()
        return self.to_internal(lo), self.to_internal(hi)

    def linear_mask(self) -> np.ndarray:
        m = np.zeros(self.size, dtype=bool)
        for s, sl in zip(self.specs, self.slices().values()):
            m[sl] = s.linear
        return m

    def to_dict(self, x: np.ndarray) -> dict[str, float | list[float]]:
        out: dict[str, float | list[float]] = {}
        for s, sl in zip(self.specs, self.slices().values()):
            val = [float(t) for t in x[sl]]
            out[s.name] = val[0] if s.size == 1 else val
        return out

    def from_dict(self, params: dict) -> np.ndarray:
        x = np.empty(self.size)
        for s, sl in zip(self.specs, self.slices().values()):
            if s.name not in params:
                raise ModelError(f"{self.kind}-fit: parameter {s.name!r} is missing")
            x[sl] = np.broadcast_to(np.asarray(params[s.name], dtype=float), (s.size,))
        return x

    def check(self, x: np.ndarray) -> str | None:
        """Why ``x`` is not a valid parameter vector (None if it is)."""
        if x.shape != (self.size,):
            return f"needs {self.size} parameters ({', '.join(s.name for s in self.specs)}), got {x.size}"
        if not np.all(np.isfinite(x)):
            return "parameters must be finite"
        for s, sl in zip(self.specs, self.slices().values()):
            if (s.log or s.positive) and np.any(x[sl] <= 0):
                return f"{s.name} must be > 0"
            if not s.log and np.any(x[sl] < 0) and s.lower >= 0:
                return f"{s.name} must be >= 0"
        return None

    def start_point(self) -> np.ndarray:
        x = np.empty(self.size)
        for s, sl in zip(self.specs, self.slices().values()):
            x[sl] = s.start * self.scale(s)
        return x

    def random_point(self, rng: np.random.Generator) -> np.ndarray:
        """A random start: every colour equal over the channels (as the paper), shapes log-uniform."""
        x = np.empty(self.size)
        for s, sl in zip(self.specs, self.slices().values()):
            lo, hi = s.typical if s.typical is not None else (s.lower, s.upper)
            u = rng.uniform()
            x[sl] = math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))) if s.log else lo + u * (hi - lo)
            x[sl] *= self.scale(s)
        return x

    # ------------------------------------------------------------- evaluation
    def evaluate(self, x: np.ndarray, smp: Samples) -> np.ndarray:
        """Cell values (n_cells, 3) for natural parameters ``x``."""
        return self.cells_and_jac(self.to_internal(x), smp, jac=False)[0]

    def cells_and_jac(self, z: np.ndarray, smp: Samples, jac: bool) -> tuple[np.ndarray, "SparseJac | None"]:
        """Cell values (n_cells, 3) and, if asked, their Jacobian in internal coordinates."""
        raise NotImplementedError

    def dense_jac(self, jac: "SparseJac") -> np.ndarray:
        """The Jacobian as a dense (n_cells, 3, P) array (tests and diagnostics)."""
        V, cols = jac
        out = np.zeros((V.shape[2], 3, self.size))
        for c in range(3):
            for k in range(cols.shape[1]):
                out[:, c, cols[c, k]] += V[c, k]
        return out


#: A Jacobian with a fixed sparsity pattern per colour channel: ``(V, cols)``; row (cell ``i``,
#: channel ``c``) has the values ``V[c, :, i]`` in the columns ``cols[c, :]`` (others are 0).
#: Colour parameters of one channel only touch that channel's rows.
SparseJac = tuple[np.ndarray, np.ndarray]
