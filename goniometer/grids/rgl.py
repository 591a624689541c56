"""The RGL grid of a run (``docs/rgl-format.md``): the incident directions of the format's
``theta_i`` / ``phi_i`` nodes, the ``n x n`` sample-space nodes the stored values live on, and the
warp that maps them to outgoing directions: an NDF ``D`` (tabulated as ``ndf``), its projected area
``sigma`` and, per incident direction, the visible-normal density on the square (``vndf``).

The NDF is the warp's, not the material's: the readers evaluate ``f cos theta_o = S(u) D / (4 sigma)``
with ``u`` the warp's sample-space point of the half vector, so any positive, normalised ``D`` gives
the right BRDF at the nodes; ``D`` only decides where the ``n x n`` nodes land. It is the mixture
``D = (1 - b) D_top + b D_1`` of the top interface's GGX (alpha floored at :data:`ALPHA_FLOOR`) and the
alpha = 1 GGX (``D_1 = 1 / pi``), ``b`` = :data:`BROAD` by default: half of the sample space resolves
the top's specular lobe, half spreads over the hemisphere for what the layers below return. With the
top's GGX alone a sharp coat over a rough base squeezes the base's broad lobe into the last columns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np

from goniometer import optics
from goniometer.grids.warp import Warp2D, pack_kernel_tables

__all__ = ["ALPHA_FLOOR", "BROAD", "DEFAULT_GRID", "RGLGrid", "RGLGridError", "check_spec", "grid_for", "parse_grid",
           "theta_nodes_deg"]

#: the sharpest lobe the warp's NDF tabulates (a smooth top's peak is narrower than any table)
ALPHA_FLOOR = 1e-3
#: weight of the alpha = 1 lobe in the warp's NDF
BROAD = 0.5
#: (N_THETA_I, N_PHI_I, N): 8 incident elevations, one azimuth (isotropic) or 9 over [-180, 180]
#: (anisotropic), 32 x 32 sample-space nodes
DEFAULT_GRID = (8, 1, 32)
DEFAULT_PHI_ANISO = 9
#: (rows, columns) of the ndf, sigma and vndf tables (rows: phi, columns: sqrt(theta / (pi / 2)))
TABLE = (64, 128)
#: the last theta_i node (the simulator traces theta < 90; the readers clamp beyond the last node)
THETA_LAST_DEG = 89.0
#: sub-points per side of a dual cell for the part of it above the horizon
VALID_SUB = 8


class RGLGridError(ValueError):
    """An RGL grid that cannot be (the message names the field and the allowed range)."""


def theta_nodes_deg(n: int) -> tuple[float, ...]:
    """The format's incident elevations: uniform in cos theta (as the RGL database's, Dupuy &
    Jakob 2018), the last at :data:`THETA_LAST_DEG`."""
    if n < 2:
        raise RGLGridError(f"rgl grid: N_THETA_I = {n} is not allowed; at least 2 incident elevations")
    t = [math.degrees(math.acos(1.0 - k / (n - 1))) for k in range(n)]
    t[-1] = THETA_LAST_DEG
    t[-2] = min(t[-2], THETA_LAST_DEG - 1.0)
    return tuple(t)


@dataclass(frozen=True)
class RGLGrid:
    """What a run on the RGL grid records. ``theta_i_deg`` / ``phi_i_deg``: the format's incident
    nodes (``phi_i_deg`` in [-180, 180]; one value: isotropic, the stored values then depend on the
    azimuth relative to it); ``n``: sample-space nodes per side; ``alpha``, ``rotation_deg``,
    ``broad``: the warp's NDF (module docstring); ``table``: rows and columns of its tables."""

    theta_i_deg: tuple[float, ...]
    phi_i_deg: tuple[float, ...] = (0.0,)
    n: int = 32
    alpha: tuple[float, float] = (1.0, 1.0)
    rotation_deg: float = 0.0
    broad: float = BROAD
    table: tuple[int, int] = TABLE
    _cache: dict = field(default_factory=dict, compare=False, repr=False, hash=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "theta_i_deg", tuple(float(x) for x in self.theta_i_deg))
        object.__setattr__(self, "phi_i_deg", tuple(float(x) for x in self.phi_i_deg))
        object.__setattr__(self, "alpha", tuple(float(x) for x in self.alpha))
        object.__setattr__(self, "table", tuple(int(x) for x in self.table))
        t = self.theta_i_deg
        if len(t) < 2 or any(not 0.0 <= x < 90.0 for x in t) or any(b <= a for a, b in zip(t, t[1:])):
            raise RGLGridError(f"rgl grid: theta_i {list(t)} must be at least 2 increasing elevations in [0, 90)")
        p = self.phi_i_deg
        if len(p) == 2 or len(p) > 1 and (p[0] != -180.0 or p[-1] != 180.0 or any(b <= a for a, b in zip(p, p[1:]))):
            raise RGLGridError(f"rgl grid: phi_i {list(p)} must be one azimuth (isotropic) or at least 3 increasing "
                               f"azimuths from -180 to 180 (what pbrt-v4 and Mitsuba 3 read without folding)")
        if len(p) == 1 and not -180.0 <= p[0] <= 180.0:
            raise RGLGridError(f"rgl grid: phi_i {p[0]:g} is outside [-180, 180]")
        if not isinstance(self.n, (int, np.integer)) or not 4 <= self.n <= 512:
            raise RGLGridError(f"rgl grid: N = {self.n!r} is outside [4, 512] (sample-space nodes per side)")
        if not all(0.0 < a <= 1.0 for a in self.alpha):
            raise RGLGridError(f"rgl grid: alpha {list(self.alpha)} must be in (0, 1]")
        if not 0.0 < self.broad <= 1.0:
            raise RGLGridError(f"rgl grid: broad {self.broad} must be in (0, 1]")
        if self.table[0] < 2 or self.table[1] < 2:
            raise RGLGridError(f"rgl grid: table {list(self.table)} needs at least 2 x 2 nodes")

    # ------------------------------------------------------------------ the incident directions

    @property
    def isotropic(self) -> bool:
        return len(self.phi_i_deg) == 1

    def simulated_phi_deg(self) -> tuple[float, ...]:
        """The azimuths traced, in [0, 360): every node's but the last (-180 and 180 are one)."""
        nodes = self.phi_i_deg if self.isotropic else self.phi_i_deg[:-1]
        return tuple(x % 360.0 for x in nodes)

    def incidents(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """(theta_deg, phi_deg) of the simulated incident directions, azimuth-major (the format's
        ``[phi_i][theta_i]`` order)."""
        th, ph = [], []
        for p in self.simulated_phi_deg():
            for t in self.theta_i_deg:
                th.append(t)
                ph.append(p)
        return tuple(th), tuple(ph)

    def to_dict(self) -> dict[str, Any]:
        return {"theta_i_deg": list(self.theta_i_deg), "phi_i_deg": list(self.phi_i_deg), "n": int(self.n),
                "alpha": list(self.alpha), "rotation_deg": self.rotation_deg, "broad": self.broad,
                "table": list(self.table)}

    @classmethod
    def from_dict(cls, d: dict) -> "RGLGrid":
        try:
            return cls(theta_i_deg=tuple(d["theta_i_deg"]), phi_i_deg=tuple(d["phi_i_deg"]), n=int(d["n"]),
                       alpha=tuple(d["alpha"]), rotation_deg=float(d["rotation_deg"]), broad=float(d["broad"]),
                       table=tuple(d["table"]))
        except (KeyError, TypeError) as e:
            raise RGLGridError(f"rgl grid: incomplete description ({e})") from None

    # ------------------------------------------------------------------ the warp's tables

    def _grid_angles(self) -> tuple[np.ndarray, np.ndarray]:
        H, W = self.table
        x = np.linspace(0.0, 1.0, W)
        y = np.linspace(0.0, 1.0, H)
        return 0.5 * math.pi * x * x, (2.0 * y - 1.0) * math.pi

    def tables(self) -> dict[str, np.ndarray]:
        """The format's warp fields, float32 as the readers take them: ``theta_i``, ``phi_i``
        (radians), ``ndf``, ``sigma`` (H, W) and ``vndf`` (N_phi_i, N_theta_i, H, W)."""
        if "tables" not in self._cache:
            theta, phi = self._grid_angles()
            T, P = np.meshgrid(theta, phi)                     # rows: phi, columns: theta
            m = _sph(T, P)
            ax, ay = self.alpha
            c, s = math.cos(math.radians(self.rotation_deg)), math.sin(math.radians(self.rotation_deg))
            ndf = _ndf(m.reshape(-1, 3), ax, ay, c, s, self.broad).reshape(T.shape)
            sigma = _sigma(m.reshape(-1, 3), ax, ay, c, s, self.broad).reshape(T.shape)
            x = np.sqrt(T / (0.5 * math.pi))
            jac = 2.0 * math.pi ** 2 * x * np.sin(T)          # d omega_m = 2 pi^2 x sin(theta) dx dy
            vndf = np.empty((len(self.phi_i_deg), len(self.theta_i_deg)) + T.shape)
            for a, pi_deg in enumerate(self.phi_i_deg):
                for b, ti_deg in enumerate(self.theta_i_deg):
                    wi = _sph(np.radians(ti_deg), np.radians(pi_deg))
                    # isotropic files hold the half vector's azimuth relative to phi_i
                    mm = _sph(T, P + np.radians(pi_deg)) if self.isotropic else m
                    d = ndf if not self.isotropic else _ndf(mm.reshape(-1, 3), ax, ay, c, s, self.broad).reshape(T.shape)
                    sig = float(_sigma(wi.reshape(1, 3), ax, ay, c, s, self.broad)[0])
                    vndf[a, b] = np.maximum(0.0, mm @ wi) * d / sig * jac
            self._cache["tables"] = {
                "theta_i": np.radians(self.theta_i_deg).astype(np.float32),
                "phi_i": np.radians(self.phi_i_deg).astype(np.float32),
                "ndf": ndf.astype(np.float32), "sigma": sigma.astype(np.float32), "vndf": vndf.astype(np.float32)}
        return self._cache["tables"]

    def warp(self, m: int) -> Warp2D:
        """The warp of simulated incident direction ``m`` (from the float32 table the file holds)."""
        key = ("warp", m)
        if key not in self._cache:
            a, b = divmod(m, len(self.theta_i_deg))
            self._cache[key] = Warp2D.from_density(self.tables()["vndf"][a, b].astype(np.float64))
        return self._cache[key]

    def light(self, m: int) -> np.ndarray:
        """Unit direction towards the light of simulated incident direction ``m``."""
        th, ph = self.incidents()
        return _sph(math.radians(th[m]), math.radians(ph[m]))

    def kernel_tables(self, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The tracer's three table arguments for simulated incident direction ``m``
        (:func:`goniometer.grids.warp.pack_kernel_tables`)."""
        th, ph = self.incidents()
        return pack_kernel_tables(self.warp(m), math.radians(ph[m]), self.isotropic)

    def node_directions(self, m: int, ux: np.ndarray, uy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Half vectors and outgoing directions (..., 3) of sample-space points for incident ``m``."""
        x, y = self.warp(m).sample(ux, uy)
        th, ph = self.incidents()
        theta_m = 0.5 * math.pi * x * x
        phi_m = (2.0 * y - 1.0) * math.pi + (math.radians(ph[m]) if self.isotropic else 0.0)
        h = _sph(theta_m, phi_m)
        l = self.light(m)
        v = 2.0 * (h @ l)[..., None] * h - l
        return h, v

    def cell_geometry(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """(area, mask) of the ``n x n`` dual cells for incident ``m``: the part of each cell's
        sample-space area whose outgoing directions lie above the horizon (the estimator's
        measure: the stored value is the energy per unit of it), and the cells wholly above it."""
        key = ("geometry", m)
        if key not in self._cache:
            n, s = self.n, VALID_SUB
            edges = np.clip((np.arange(n + 1) - 0.5) / (n - 1), 0.0, 1.0)
            width = np.diff(edges)
            # sub-point centres of every dual cell, per axis: (n, s)
            sub = edges[:-1, None] + width[:, None] * (np.arange(s) + 0.5)[None, :] / s
            ux = np.broadcast_to(sub[None, :, None, :], (n, n, s, s))
            uy = np.broadcast_to(sub[:, None, :, None], (n, n, s, s))
            _, v = self.node_directions(m, ux, uy)
            frac = np.mean(v[..., 2] > 0.0, axis=(2, 3))
            area = width[:, None] * width[None, :] * frac
            mask = frac == 1.0
            area.setflags(write=False)
            mask.setflags(write=False)
            self._cache[key] = (area, mask)
        return self._cache[key]


def _sph(theta, phi) -> np.ndarray:
    theta = np.asarray(theta, dtype=np.float64)
    phi = np.asarray(phi, dtype=np.float64)
    st = np.sin(theta)
    return np.stack(np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), np.cos(theta)), axis=-1)


@numba.njit(cache=True, error_model='numpy')
def _ndf(m, ax, ay, c, s, broad):
    """The warp's NDF at unit normals ``m`` (N, 3): ``(1 - broad) D_GGX(ax, ay, rotated) + broad / pi``."""
    out = np.empty(m.shape[0])
    for i in range(m.shape[0]):
        x = c * m[i, 0] + s * m[i, 1]
        y = -s * m[i, 0] + c * m[i, 1]
        z = m[i, 2]
        out[i] = (1.0 - broad) * optics.ggx_d(x, y, z, ax, ay) + (broad / math.pi if z > 0.0 else 0.0)
    return out


@numba.njit(cache=True, error_model='numpy')
def _sigma(w, ax, ay, c, s, broad):
    """Projected area ``sigma(w) = Int max(0, w.m) D(m) dm`` of the warp's NDF at unit ``w`` (N, 3):
    ``cos theta (1 + Lambda(w))`` per GGX lobe (Smith; ``(1 + cos theta) / 2`` for alpha = 1)."""
    out = np.empty(w.shape[0])
    for i in range(w.shape[0]):
        x = c * w[i, 0] + s * w[i, 1]
        y = -s * w[i, 0] + c * w[i, 1]
        z = max(w[i, 2], 0.0)
        if z > 0.0:
            top = z * (1.0 + optics.ggx_lambda(x, y, z, ax, ay))
        else:
            # seen edge on: the limit of cos (1 + Lambda) = alpha sin(theta) / 2
            top = 0.5 * math.sqrt((ax * x) ** 2 + (ay * y) ** 2)
        out[i] = (1.0 - broad) * top + broad * 0.5 * (1.0 + z)
    return out


def parse_grid(text: str) -> tuple[int, int, int]:
    """``N_THETA_IxN_PHI_IxN`` (e.g. ``8x1x32``) as three integers, checked (:func:`check_spec`)."""
    parts = text.lower().split("x")
    try:
        if len(parts) != 3:
            raise ValueError
        a, b, c = (int(p) for p in parts)
    except ValueError:
        raise RGLGridError(f"--rgl-grid: {text!r} is not of the form N_THETA_IxN_PHI_IxN (e.g. 8x1x32)") from None
    check_spec(a, b, c, "--rgl-grid")
    return a, b, c


def check_spec(n_theta_i: int | None, n_phi_i: int | None, n: int | None, where: str = "rgl grid") -> None:
    """Raise :class:`RGLGridError` unless the counts are allowed (None: the default)."""
    if n_theta_i is not None and not 2 <= n_theta_i <= 90:
        raise RGLGridError(f"{where}: N_THETA_I = {n_theta_i} is outside [2, 90]")
    if n_phi_i is not None and n_phi_i != 1 and not 3 <= n_phi_i <= 361:
        raise RGLGridError(f"{where}: N_PHI_I = {n_phi_i} is not allowed; 1 (isotropic) or 3 to 361 azimuths over "
                           f"[-180, 180]")
    if n is not None and not 4 <= n <= 512:
        raise RGLGridError(f"{where}: N = {n} is outside [4, 512]")


def grid_for(stack, n_theta_i: int | None = None, n_phi_i: int | None = None, n: int | None = None) -> RGLGrid:
    """The RGL grid of ``stack`` (its top interface's GGX sets the warp's sharp lobe): ``n_phi_i``
    defaults to 1 for an isotropic stack and :data:`DEFAULT_PHI_ANISO` for an anisotropic one."""
    check_spec(n_theta_i, n_phi_i, n)
    top = stack.layers[0]
    aniso = stack.is_anisotropic
    nt = DEFAULT_GRID[0] if n_theta_i is None else n_theta_i
    nph = (DEFAULT_PHI_ANISO if aniso else 1) if n_phi_i is None else n_phi_i
    nn = DEFAULT_GRID[2] if n is None else n
    phi = (0.0,) if nph == 1 else tuple(-180.0 + 360.0 * k / (nph - 1) for k in range(nph))
    if hasattr(top, "alpha_xy"):
        alpha = tuple(max(ALPHA_FLOOR, a) for a in top.alpha_xy)
        rotation = float(top.rotation_deg)
    else:
        alpha, rotation = (1.0, 1.0), 0.0
    return RGLGrid(theta_i_deg=theta_nodes_deg(nt), phi_i_deg=phi, n=nn, alpha=alpha, rotation_deg=rotation)
