"""Which of our stacks the production coat models represent: one dielectric coat interface, an
optional purely absorbing medium, and a conductor or Lambertian base (``docs/production-models.md``,
"Stacks"). Anisotropy and scattering media are refused by :meth:`models.base.Model.reason`."""

from __future__ import annotations

from goniometer.stack import Interface, Lambertian, Medium, Stack
from models.base import CoatedBase, coated_base

STRUCTURE = "[dielectric coat interface, optional absorbing medium, conductor or Lambertian base]"


def _kind(layer: object) -> str:
    if isinstance(layer, Interface):
        return "conductor interface" if layer.is_conductor else "dielectric interface"
    if isinstance(layer, Medium):
        return "medium"
    if isinstance(layer, Lambertian):
        return "Lambertian base"
    return type(layer).__name__


def coat_reason(stack: Stack) -> str | None:
    """Why ``stack`` is not a single coat over a metal or diffuse base (None if it is)."""
    layers = list(stack.layers)
    kinds = ", ".join(_kind(x) for x in layers)
    if not layers or not isinstance(layers[0], Interface) or layers[0].is_conductor:
        return f"needs a dielectric coat on top: {STRUCTURE}; this stack is [{kinds}]"
    if len(layers) == 1:
        return f"missing coat: a single interface has no base below a coat; needs {STRUCTURE}"
    cb = coated_base(stack)
    if cb is None:
        n_coats = sum(isinstance(x, Interface) and not x.is_conductor for x in layers)
        extra = f" (it has {n_coats} dielectric interfaces: one coat only)" if n_coats > 1 else ""
        return f"needs exactly {STRUCTURE}; this stack is [{kinds}]{extra}"
    if cb.base == "dielectric":
        return ("a dielectric base interface (a transmitting slab) is neither a metal nor a diffuse base; "
                f"needs {STRUCTURE}")
    return None


def coat_structure(stack: Stack) -> CoatedBase:
    """The :class:`models.base.CoatedBase` of a stack :func:`coat_reason` accepts (ValueError otherwise)."""
    reason = coat_reason(stack)
    if reason is not None:
        raise ValueError(reason)
    cb = coated_base(stack)
    assert cb is not None
    return cb
