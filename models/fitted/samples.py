"""Direction samples of the fitted models grouped by cell (:class:`Samples`), with the per-sample
geometry the families evaluate: ``l``, ``v`` unit vectors pointing away from the surface (``z`` the
macro normal), ``h = normalize(l + v)``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Samples:
    """Direction samples grouped by cell: cell ``i`` owns samples ``start[i]:start[i + 1]``.

    ``l``/``v`` (N, 3) unit light and view directions, ``w`` (N,) sub-cell weights normalised to
    sum 1 over each cell, ``start`` (n_cells + 1,) int64 offsets. Derived per-sample geometry is
    computed once here; invalid samples (``l_z <= 0``, ``v_z <= 0``, non-finite ``v``) get weight 0.
    """

    l: np.ndarray
    v: np.ndarray
    w: np.ndarray
    start: np.ndarray

    def __post_init__(self) -> None:
        l, v = self.l, self.v
        ok = (l[:, 2] > 0.0) & (v[:, 2] > 0.0) & np.all(np.isfinite(v), axis=1)
        self.valid = ok
        v = np.where(ok[:, None], v, np.array([0.0, 0.0, 1.0]))
        self.v = v
        h = l + v
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        self.lz = np.where(ok, l[:, 2], 0.0)
        self.vz = np.where(ok, v[:, 2], 0.0)
        self.cos_h = h[:, 2]
        lh = np.clip(np.sum(l * h, axis=1), 0.0, 1.0)
        self.schlick = (1.0 - lh) ** 5  # Schlick weight m: F = F0 (1 - m) + m
        with np.errstate(divide="ignore", invalid="ignore"):
            self.tan_l = np.where(l[:, 2] > 0, np.sqrt(np.maximum(0.0, 1.0 - l[:, 2] ** 2)) / l[:, 2], np.inf)
            self.tan_v = np.where(self.vz > 0, np.sqrt(np.maximum(0.0, 1.0 - self.vz ** 2)) / self.vz, np.inf)
        self.ft2 = (l[:, 0] + v[:, 0]) ** 2 + (l[:, 1] + v[:, 1]) ** 2
        with np.errstate(divide="ignore"):
            self.ln_tan_l = np.log(self.tan_l)
            self.ln_tan_v = np.log(self.tan_v)
            self.ln_tan2_h = np.log(np.maximum(0.0, 1.0 - self.cos_h ** 2)) - np.log(self.cos_h ** 2)
            self.ln_cos2_h = np.log(self.cos_h ** 2)
        self.ln_tan2_h = np.where(ok, self.ln_tan2_h, -np.inf)
        self.ln_cos2_h = np.where(ok, self.ln_cos2_h, 0.0)
        self.w = np.ascontiguousarray(np.where(ok, self.w, 0.0))
        self.start = np.ascontiguousarray(self.start, dtype=np.int64)

    @property
    def n_cells(self) -> int:
        return self.start.shape[0] - 1

    @classmethod
    def directions(cls, l: np.ndarray, v: np.ndarray) -> "Samples":
        """One sample per direction (model evaluation): ``l`` (3,), ``v`` (N, 3)."""
        v = np.ascontiguousarray(v, dtype=np.float64).reshape(-1, 3)
        ll = np.ascontiguousarray(np.broadcast_to(np.asarray(l, dtype=np.float64), v.shape))
        return cls(ll, v, np.ones(v.shape[0]), np.arange(v.shape[0] + 1))
