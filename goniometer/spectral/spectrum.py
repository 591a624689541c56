"""Spectral values: tabulated spectra, Cauchy and Sellmeier dispersion, and their TOML form.

Wavelengths are in nanometres everywhere in the API; the dispersion formulas take their
coefficients in micrometres (``b_um2``, ``c_um4``, ``c_um2``) as optics references print them.
Every value has ``at(wavelength_nm) -> float64 array``, ``covers(lo, hi)`` and ``to_dict()``
(the TOML/JSON table :func:`from_toml` reads back).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

#: the visible range of spectral runs (nm); the dispersion formulas are validated over it
RANGE_NM = (360.0, 830.0)

# tolerance on the ends of a tabulated range: wavelengths computed in floating point (bin edges,
# centres) that land a rounding error outside [first, last] are clipped to it
_END_SLACK = 1e-9


class SpectrumError(ValueError):
    """A spectral value that cannot be built or evaluated; the message is one line and names where."""


def _short(values: Any, limit: int = 8) -> str:
    seq = list(values)
    text = ", ".join(f"{v:g}" if _is_number(v) else repr(v) for v in seq[:limit])
    return f"[{text}{', ...' if len(seq) > limit else ''}]"


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def _numbers(seq: Any, where: str) -> tuple[float, ...]:
    if isinstance(seq, (str, bytes)) or not hasattr(seq, "__iter__"):
        raise SpectrumError(f"{where}: must be a list of numbers (got {seq!r})")
    items = list(seq)
    bad = [x for x in items if not _is_number(x)]
    if bad:
        raise SpectrumError(f"{where}: must be a list of numbers (got {bad[0]!r} in {_short(items)})")
    return tuple(float(x) for x in items)


def _check_table(wavelength_nm: tuple[float, ...], value: tuple[float, ...], where: str) -> None:
    if len(wavelength_nm) != len(value):
        raise SpectrumError(f"{where}: a table needs wavelength_nm and value of the same length "
                            f"(got {len(wavelength_nm)} and {len(value)})")
    if len(wavelength_nm) < 2:
        raise SpectrumError(f"{where}: a table needs at least 2 entries (got {len(wavelength_nm)})")
    wl = np.asarray(wavelength_nm)
    if not (np.all(np.isfinite(wl)) and np.all(wl > 0) and np.all(np.diff(wl) > 0)):
        raise SpectrumError(f"{where}.wavelength_nm: must be strictly increasing and positive "
                            f"(got {_short(wavelength_nm)})")
    if not np.all(np.isfinite(np.asarray(value))):
        raise SpectrumError(f"{where}.value: must be finite (got {_short(value)})")


def _as_nm(wavelength_nm: np.ndarray | float) -> np.ndarray:
    return np.asarray(wavelength_nm, dtype=np.float64)


@dataclass(frozen=True)
class Spectrum:
    """A tabulated spectrum, linear between the nodes, undefined outside ``[first, last]`` nm."""

    wavelength_nm: tuple[float, ...]
    value: tuple[float, ...]
    source: str = ""

    def __post_init__(self) -> None:
        where = f"Spectrum({self.source})" if self.source else "Spectrum"
        object.__setattr__(self, "wavelength_nm", _numbers(self.wavelength_nm, f"{where}.wavelength_nm"))
        object.__setattr__(self, "value", _numbers(self.value, f"{where}.value"))
        if not isinstance(self.source, str):
            raise SpectrumError(f"{where}.source: must be a string (got {self.source!r})")
        _check_table(self.wavelength_nm, self.value, where)

    @property
    def range_nm(self) -> tuple[float, float]:
        return self.wavelength_nm[0], self.wavelength_nm[-1]

    def covers(self, lo: float, hi: float) -> bool:
        first, last = self.range_nm
        return first * (1 - _END_SLACK) <= lo and hi <= last * (1 + _END_SLACK)

    def at(self, wavelength_nm: np.ndarray | float) -> np.ndarray:
        """The piecewise-linear interpolant at ``wavelength_nm`` (float64, the shape of the input)."""
        lam = _as_nm(wavelength_nm)
        first, last = self.range_nm
        outside = ~((lam >= first * (1 - _END_SLACK)) & (lam <= last * (1 + _END_SLACK)))
        if np.any(outside):
            bad = lam[outside] if lam.ndim else lam
            name = self.source or "spectrum"
            raise SpectrumError(f"{name}: wavelength {float(np.ravel(bad)[0])!r} nm lies outside the "
                                f"tabulated range [{first:g}, {last:g}] nm")
        return np.interp(lam, self.wavelength_nm, self.value).astype(np.float64)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"wavelength_nm": list(self.wavelength_nm), "value": list(self.value)}
        if self.source:
            out["source"] = self.source
        return out


def _check_positive_over_range(at, where: str, what: str) -> None:
    lam = np.linspace(*RANGE_NM, 471)
    n = at(lam)
    if not np.all(np.isfinite(n) & (n > 0)):
        i = int(np.argmax(~(np.isfinite(n) & (n > 0))))
        raise SpectrumError(f"{where}: the index must be positive over {RANGE_NM[0]:g}-{RANGE_NM[1]:g} nm "
                            f"(got n = {float(n[i]):g} at {float(lam[i]):g} nm with {what})")


@dataclass(frozen=True)
class Cauchy:
    """Cauchy's dispersion ``n = a + b / lambda^2 + c / lambda^4``, lambda in micrometres."""

    a: float
    b_um2: float = 0.0
    c_um4: float = 0.0

    def __post_init__(self) -> None:
        for name in ("a", "b_um2", "c_um4"):
            x = getattr(self, name)
            if not _is_number(x) or not math.isfinite(x):
                raise SpectrumError(f"Cauchy.{name}: must be a finite number (got {x!r})")
            object.__setattr__(self, name, float(x))
        _check_positive_over_range(self.at, "Cauchy", f"a = {self.a:g}, b_um2 = {self.b_um2:g}, c_um4 = {self.c_um4:g}")

    def covers(self, lo: float, hi: float) -> bool:
        return True

    def at(self, wavelength_nm: np.ndarray | float) -> np.ndarray:
        inv2 = 1.0 / (_as_nm(wavelength_nm) * 1e-3) ** 2
        return self.a + inv2 * (self.b_um2 + inv2 * self.c_um4)

    def to_dict(self) -> dict[str, Any]:
        return {"cauchy": [self.a, self.b_um2, self.c_um4]}


@dataclass(frozen=True)
class Sellmeier:
    """Sellmeier's dispersion ``n^2 = 1 + sum_i b_i lambda^2 / (lambda^2 - c_i)``, lambda in micrometres.

    Validated over 360-830 nm: no pole ``lambda^2 = c_i`` there and ``n^2 > 0`` throughout.
    """

    b: tuple[float, ...]
    c_um2: tuple[float, ...]

    def __post_init__(self) -> None:
        b = _numbers(self.b, "Sellmeier.b")
        c = _numbers(self.c_um2, "Sellmeier.c_um2")
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "c_um2", c)
        if len(b) != len(c) or not b:
            raise SpectrumError(f"Sellmeier: b and c_um2 need the same, non-zero length (got {len(b)} and {len(c)})")
        if not all(math.isfinite(x) for x in b + c):
            raise SpectrumError(f"Sellmeier: coefficients must be finite (got b = {_short(b)}, c_um2 = {_short(c)})")
        lo, hi = RANGE_NM
        poles = [x for x in c if (lo * 1e-3) ** 2 <= x <= (hi * 1e-3) ** 2]
        if poles:
            raise SpectrumError(f"Sellmeier: a pole lambda^2 = c_i within {lo:g}-{hi:g} nm (c_um2 = {poles[0]:g}, "
                                f"at {1e3 * math.sqrt(poles[0]):g} nm)")
        if not self.covers(lo, hi):
            raise SpectrumError(f"Sellmeier: n^2 must be positive over {lo:g}-{hi:g} nm "
                                f"(b = {_short(b)}, c_um2 = {_short(c)})")

    def _n2(self, lam_nm: np.ndarray) -> np.ndarray:
        l2 = (lam_nm * 1e-3) ** 2
        n2 = np.ones_like(l2)
        for b, c in zip(self.b, self.c_um2):
            n2 = n2 + b * l2 / (l2 - c)
        return n2

    def covers(self, lo: float, hi: float) -> bool:
        l2lo, l2hi = (lo * 1e-3) ** 2, (hi * 1e-3) ** 2
        if any(l2lo <= c <= l2hi for c in self.c_um2):
            return False
        with np.errstate(divide="ignore", invalid="ignore"):
            n2 = self._n2(np.linspace(lo, hi, max(2, int(abs(hi - lo)) + 1)))
        return bool(np.all(np.isfinite(n2) & (n2 > 0)))

    def at(self, wavelength_nm: np.ndarray | float) -> np.ndarray:
        lam = _as_nm(wavelength_nm)
        with np.errstate(divide="ignore", invalid="ignore"):
            n2 = self._n2(lam)
        if not np.all(np.isfinite(n2) & (n2 > 0)):
            bad = np.ravel(lam[~(np.isfinite(n2) & (n2 > 0))] if lam.ndim else lam)[0]
            raise SpectrumError(f"Sellmeier: n^2 <= 0 or a pole at {float(bad):g} nm "
                                f"(b = {_short(self.b)}, c_um2 = {_short(self.c_um2)})")
        return np.sqrt(n2)

    def to_dict(self) -> dict[str, Any]:
        return {"sellmeier": {"b": list(self.b), "c_um2": list(self.c_um2)}}


#: the spectral values a material parameter can hold (``isinstance(x, Spectral)`` works)
Spectral = Spectrum | Cauchy | Sellmeier


def is_spectral(x: Any) -> bool:
    """Whether ``x`` is a :data:`Spectral` value (a :class:`Spectrum`, :class:`Cauchy` or :class:`Sellmeier`)."""
    return isinstance(x, (Spectrum, Cauchy, Sellmeier))


_FORMS = ("{wavelength_nm = [...], value = [...]} (optionally source = \"...\"), "
          "{cauchy = [A, B] or [A, B, C]}, {sellmeier = {b = [...], c_um2 = [...]}}")


def _unknown(keys: set[str], allowed: tuple[str, ...], where: str) -> None:
    extra = sorted(keys - set(allowed))
    if extra:
        raise SpectrumError(f"{where}: unknown key{'s' if len(extra) > 1 else ''} "
                            f"{', '.join(map(repr, extra))} (allowed: {', '.join(allowed)})")


def _rewhere(error: SpectrumError, old: str, where: str) -> SpectrumError:
    text = str(error)
    return SpectrumError(where + text[len(old):] if text.startswith(old) else f"{where}: {text}")


def from_toml(value: Any, where: str) -> Spectrum | Cauchy | Sellmeier:
    """A spectral value from its TOML table; ``where`` (e.g. ``"layers[2].ior"``) prefixes every error.

    Forms: ``{wavelength_nm = [...], value = [...]}`` with an optional ``source``;
    ``{cauchy = [A, B]}`` or ``[A, B, C]`` (B in um^2, C in um^4);
    ``{sellmeier = {b = [...], c_um2 = [...]}}``. Named conductors: :func:`named_conductor`.
    """
    if not isinstance(value, dict):
        raise SpectrumError(f"{where}: a spectral value is a table, one of {_FORMS} (got {value!r})")
    keys = set(value)
    if "cauchy" in keys:
        _unknown(keys, ("cauchy",), where)
        coeffs = _numbers(value["cauchy"], f"{where}.cauchy")
        if len(coeffs) not in (2, 3):
            raise SpectrumError(f"{where}.cauchy: must be [A, B] or [A, B, C] (got {list(coeffs)})")
        try:
            return Cauchy(*coeffs)
        except SpectrumError as e:
            raise _rewhere(e, "Cauchy", f"{where}.cauchy") from None
    if "sellmeier" in keys:
        _unknown(keys, ("sellmeier",), where)
        table = value["sellmeier"]
        if not isinstance(table, dict):
            raise SpectrumError(f"{where}.sellmeier: must be a table {{b = [...], c_um2 = [...]}} (got {table!r})")
        _unknown(set(table), ("b", "c_um2"), f"{where}.sellmeier")
        for key in ("b", "c_um2"):
            if key not in table:
                raise SpectrumError(f"{where}.sellmeier: missing {key!r} (needs b and c_um2)")
        b = _numbers(table["b"], f"{where}.sellmeier.b")
        c = _numbers(table["c_um2"], f"{where}.sellmeier.c_um2")
        try:
            return Sellmeier(b, c)
        except SpectrumError as e:
            raise _rewhere(e, "Sellmeier", f"{where}.sellmeier") from None
    if "wavelength_nm" in keys or "value" in keys:
        _unknown(keys, ("wavelength_nm", "value", "source"), where)
        missing = [k for k in ("wavelength_nm", "value") if k not in keys]
        if missing:
            raise SpectrumError(f"{where}: a table needs wavelength_nm and value (missing {missing[0]})")
        wl = _numbers(value["wavelength_nm"], f"{where}.wavelength_nm")
        val = _numbers(value["value"], f"{where}.value")
        source = value.get("source", "")
        if not isinstance(source, str):
            raise SpectrumError(f"{where}.source: must be a string (got {source!r})")
        _check_table(wl, val, where)
        return Spectrum(wl, val, source)
    if keys:
        raise SpectrumError(f"{where}: unknown key{'s' if len(keys) > 1 else ''} "
                            f"{', '.join(map(repr, sorted(keys)))}; a spectral value is one of {_FORMS}")
    raise SpectrumError(f"{where}: an empty table; a spectral value is one of {_FORMS}")
