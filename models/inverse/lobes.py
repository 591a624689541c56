"""The inputs and plain values of the inverse method (Bati 2021): lobes, picks, options, errors.

A :class:`Lobe` is a requested BRDF lobe at normal incidence: energy ``R`` (scalar or RGB) and
variance ``sigma`` (Belcour's ``f(alpha) = alpha^1.1 / (1 - alpha^1.1)``), made of 1 or 2
interfaces (the paper's figure 3). A :class:`Pick` chooses a point of a lobe's equivalence class
(choice 6), :class:`InverseOptions` holds the method's switches (choices 2, 3 and 5);
:class:`Interval` is a bound of a class and :func:`jsonable` turns numpy values and intervals
into JSON values. The method, its equations and its choices: ``docs/inverse.md``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

RGB = tuple[float, float, float]

ETA_MAX_DEFAULT = 4.0
#: eta1 samples of the N1 scan (choice 5 of docs/inverse.md)
N_SCAN = 128
#: relative tolerance for "the channels of R are equal" (achromatic lobe)
ACHROMATIC_RTOL = 1e-9


class InverseError(ValueError):
    """Invalid input to the inverse method (malformed lobe, out-of-range value, bad pick name)."""


class NotAchievable(ValueError):
    """The requested lobes have no physically achievable stack.

    ``reason`` says why (with the bound that is violated when there is one), ``lobe`` is the
    1-based index of the first lobe that failed (0 if not lobe specific).
    """

    def __init__(self, reason: str, lobe: int = 0) -> None:
        super().__init__(f"not physically achievable: {reason}")
        self.reason = reason
        self.lobe = lobe


class PickError(InverseError):
    """An explicit pick lies outside its class."""


# ============================================================================ input: lobes

def as_rgb(x: Any, name: str) -> np.ndarray:
    """``x`` (a number or 3 numbers) as a finite RGB float array; :class:`InverseError` naming ``name``."""
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        a = np.full(3, float(a))
    if a.shape != (3,):
        raise InverseError(f"{name}: expected a number or 3 numbers (R, G, B), got {x!r}")
    if not np.all(np.isfinite(a)):
        raise InverseError(f"{name}: {x!r} is not finite")
    return a


@dataclass(frozen=True)
class Lobe:
    """A requested BRDF lobe at normal incidence: energy ``R`` (scalar or RGB, each in (0, 1)),
    variance ``sigma >= 0`` (Belcour's variance, ``f(alpha)``), made of ``layers`` = 1 or 2 interfaces."""

    R: RGB | float
    sigma: float = 0.0
    layers: int = 1

    def __post_init__(self) -> None:
        r = as_rgb(self.R, "R")
        if np.any(r < 0.0) or np.any(r >= 1.0):
            raise InverseError(f"R: every energy must be in [0, 1), got {fmt_rgb(r)}")
        if np.any(r == 0.0):
            raise InverseError(f"R: every channel needs a positive energy, got {fmt_rgb(r)} (a zero would need an "
                               "infinitely absorbing medium; use a small value such as 1e-4)")
        object.__setattr__(self, "R", tuple(float(x) for x in r))
        s = self.sigma
        if isinstance(s, bool) or not isinstance(s, (int, float, np.floating, np.integer)) or not math.isfinite(s):
            raise InverseError(f"sigma: {s!r} is not a finite number")
        if s < 0.0:
            raise InverseError(f"sigma: the variance must be >= 0, got {s:g}")
        object.__setattr__(self, "sigma", float(s))
        if isinstance(self.layers, bool) or self.layers not in (1, 2):
            raise InverseError(f"layers: a lobe has 1 or 2 layers (Bati 2021 figure 3), got {self.layers!r}")

    @property
    def rgb(self) -> np.ndarray:
        return np.asarray(self.R, dtype=float)

    @property
    def achromatic(self) -> bool:
        r = self.rgb
        return bool(np.ptp(r) <= ACHROMATIC_RTOL * np.max(r))

    def describe(self) -> str:
        return f"R={fmt_rgb(self.rgb)} sigma={self.sigma:g} layers={self.layers}"


_LOBE_KEYS = ("R", "sigma", "layers")


def parse_lobe(text: str) -> Lobe:
    """Parse ``"R=0.03,0.06,0.09 sigma=0.05 layers=2"`` (keys in any order; ``R`` required, one or
    three numbers; ``sigma`` default 0; ``layers`` default 1). Raises :class:`InverseError`."""
    if not isinstance(text, str) or not text.strip():
        raise InverseError("empty lobe (expected e.g. \"R=0.03,0.06,0.09 sigma=0.05 layers=2\")")
    values: dict[str, str] = {}
    for token in text.replace(";", " ").split():
        if "=" not in token:
            raise InverseError(f"lobe {text!r}: {token!r} is not KEY=VALUE (keys: R, sigma, layers)")
        key, value = token.split("=", 1)
        key = key.strip()
        if key not in _LOBE_KEYS:
            raise InverseError(f"lobe {text!r}: unknown key {key!r} (keys: R, sigma, layers)")
        if key in values:
            raise InverseError(f"lobe {text!r}: {key} given twice")
        values[key] = value.strip()
    if "R" not in values:
        raise InverseError(f"lobe {text!r}: R is required (e.g. R=0.04 or R=0.03,0.06,0.09)")
    parts = [p for p in values["R"].split(",")]
    try:
        r = [float(p) for p in parts]
    except ValueError:
        raise InverseError(f"lobe {text!r}: R={values['R']!r} is not one or three numbers") from None
    if len(r) not in (1, 3):
        raise InverseError(f"lobe {text!r}: R needs one or three numbers, got {len(r)}")
    try:
        sigma = float(values.get("sigma", "0"))
    except ValueError:
        raise InverseError(f"lobe {text!r}: sigma={values['sigma']!r} is not a number") from None
    try:
        layers_f = float(values.get("layers", "1"))
    except ValueError:
        raise InverseError(f"lobe {text!r}: layers={values['layers']!r} is not 1 or 2") from None
    if layers_f != int(layers_f):
        raise InverseError(f"lobe {text!r}: layers={values['layers']!r} is not 1 or 2")
    try:
        return Lobe(tuple(r) if len(r) == 3 else r[0], sigma, int(layers_f))
    except InverseError as e:
        raise InverseError(f"lobe {text!r}: {e}") from None


@dataclass(frozen=True)
class InverseOptions:
    """Switches of the method (choices 2, 3 and 5 of docs/inverse.md)."""

    eta_max: float = ETA_MAX_DEFAULT
    top_variance: str = "exact"
    variance_channel: str = "minimax"
    height_correlated: bool = False
    n_scan: int = N_SCAN
    cache_dir: str | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.eta_max, (int, float)) and math.isfinite(self.eta_max) and 1.0 < self.eta_max <= 16.0):
            raise InverseError(f"eta_max: must be in (1, 16], got {self.eta_max!r}")
        if self.top_variance not in ("exact", "paper"):
            raise InverseError(f"top_variance: {self.top_variance!r} is not one of exact, paper")
        if self.variance_channel not in ("max", "minimax"):
            raise InverseError(f"variance_channel: {self.variance_channel!r} is not one of max, minimax")
        if not isinstance(self.n_scan, int) or self.n_scan < 8:
            raise InverseError(f"n_scan: must be an integer >= 8, got {self.n_scan!r}")


# ============================================================================ picks

@dataclass(frozen=True)
class Pick:
    """Which point of a lobe's equivalence class to take (every field optional; None = default,
    choice 6 of docs/inverse.md).

    * ``u1`` / ``eta1``: the first index -- position in [0, 1] along N1 (2-layer) or along the
      conductor class (1-layer conductor; scalar or RGB), or along the chosen root's branch from
      its ``tau = 0`` end (1-layer dielectric; default 0); or the absolute index itself (RGB for
      a conductor).
    * ``root``: 1-layer dielectric, ``"upper"`` (eta1 > eta_n) or ``"lower"``.
    * ``u2`` / ``eta2``: 2-layer lobes, the second index: position in N2 (dielectric) or in the
      conductor class (scalar or RGB), or the absolute index (RGB for a conductor).
    * ``tau0``: optical depth (scalar or RGB) of a medium above the lobe's first interface
      (2-layer lobes and conductors; for 1-layer dielectrics it follows from eta1).
    * ``tau1``: 2-layer conductor lobes, optical depth between the two interfaces (for a 2-layer
      dielectric it follows from eta2, eq. 13).
    """

    u1: float | RGB | None = None
    eta1: float | RGB | None = None
    root: str | None = None
    u2: float | RGB | None = None
    eta2: float | RGB | None = None
    tau0: float | RGB | None = None
    tau1: float | RGB | None = None

    def __post_init__(self) -> None:
        for name in ("u1", "u2"):
            v = getattr(self, name)
            if v is not None:
                a = as_rgb(v, name)
                if np.any(a < 0.0) or np.any(a > 1.0):
                    raise InverseError(f"{name}: a position in a class is in [0, 1], got {v!r}")
        for name in ("eta1", "eta2"):
            v = getattr(self, name)
            if v is not None and np.any(as_rgb(v, name) <= 0.0):
                raise InverseError(f"{name}: an index must be > 0, got {v!r}")
        for name in ("tau0", "tau1"):
            v = getattr(self, name)
            if v is not None and np.any(as_rgb(v, name) < 0.0):
                raise InverseError(f"{name}: an optical depth must be >= 0, got {v!r}")
        if self.root is not None and self.root not in ("upper", "lower"):
            raise InverseError(f"root: {self.root!r} is not one of upper, lower")
        if self.u1 is not None and self.eta1 is not None:
            raise InverseError("give either u1 or eta1, not both")
        if self.u2 is not None and self.eta2 is not None:
            raise InverseError("give either u2 or eta2, not both")

    @property
    def is_default(self) -> bool:
        return all(getattr(self, f) is None for f in ("u1", "eta1", "root", "u2", "eta2", "tau0", "tau1"))

    def fields(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if v is not None}


PICK_FIELDS = ("u1", "eta1", "root", "u2", "eta2", "tau0", "tau1")


def as_pick(p: Pick | dict | None) -> Pick:
    if p is None:
        return Pick()
    if isinstance(p, Pick):
        return p
    if isinstance(p, dict):
        unknown = sorted(set(p) - set(PICK_FIELDS))
        if unknown:
            raise InverseError(f"pick: unknown choice {unknown[0]!r} (choices: {', '.join(PICK_FIELDS)})")
        return Pick(**p)
    raise InverseError(f"pick: expected a Pick or a dict, got {type(p).__name__}")


def parse_picks(text: str, n_lobes: int) -> list[Pick]:
    """Parse ``--pick``: ``"center"`` (every default) or space-separated ``K.NAME=VALUE`` items,
    ``K`` the 1-based lobe index, ``NAME`` one of :data:`PICK_FIELDS`, ``VALUE`` a number, three
    comma-separated numbers, or upper/lower for ``root`` (e.g. ``"1.eta1=1.6 2.u2=0.2 2.tau1=0,0.3,0"``)."""
    picks: list[dict[str, Any]] = [dict() for _ in range(n_lobes)]
    text = text.strip()
    if text in ("", "center", "centre", "default"):
        return [Pick() for _ in range(n_lobes)]
    for token in text.replace(";", " ").split():
        m = re.fullmatch(r"(\d+)\.([a-z0-9_]+)=(.+)", token)
        if not m:
            raise InverseError(f"--pick: {token!r} is not K.NAME=VALUE (e.g. 1.eta1=1.6, 2.u2=0.3, 2.tau1=0,0.3,0)")
        k, name, value = int(m.group(1)), m.group(2), m.group(3)
        if not 1 <= k <= n_lobes:
            raise InverseError(f"--pick: {token!r}: lobe {k} does not exist (there are {n_lobes})")
        if name not in PICK_FIELDS:
            raise InverseError(f"--pick: {token!r}: unknown choice {name!r} (choices: {', '.join(PICK_FIELDS)})")
        if name in picks[k - 1]:
            raise InverseError(f"--pick: {k}.{name} given twice")
        if name == "root":
            picks[k - 1][name] = value
            continue
        try:
            nums = [float(x) for x in value.split(",")]
        except ValueError:
            raise InverseError(f"--pick: {token!r}: {value!r} is not a number or three numbers") from None
        if len(nums) not in (1, 3):
            raise InverseError(f"--pick: {token!r}: expected one or three numbers")
        picks[k - 1][name] = nums[0] if len(nums) == 1 else tuple(nums)
    out = []
    for k, d in enumerate(picks):
        try:
            out.append(Pick(**d))
        except InverseError as e:
            raise InverseError(f"--pick: lobe {k + 1}: {e}") from None
    return out


# ============================================================================ values

def fmt_rgb(a: Any) -> str:
    """An RGB value for messages: one number if the channels are equal, else ``[r, g, b]`` (4 digits)."""
    a = np.atleast_1d(np.asarray(a, dtype=float))
    if a.size == 3 and np.ptp(a) == 0.0:
        return f"{a[0]:.4g}"
    return "[" + ", ".join(f"{x:.4g}" for x in a) + "]"


@dataclass(frozen=True)
class Interval:
    """A closed interval ``[lo, hi]`` of a class (an index range)."""

    lo: float
    hi: float

    @property
    def length(self) -> float:
        return self.hi - self.lo

    def contains(self, x: float, tol: float = 1e-9) -> bool:
        return self.lo - tol <= x <= self.hi + tol

    def to_list(self) -> list[float]:
        return [self.lo, self.hi]


def jsonable(x: Any) -> Any:
    """``x`` with numpy arrays and scalars, tuples and :class:`Interval` turned into JSON values
    (non-finite floats: NaN -> None, +-inf -> "inf"/"-inf"), recursively through dicts and lists."""
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, Interval):
        return x.to_list()
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else (None if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.bool_,)):
        return bool(x)
    return x
