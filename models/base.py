"""The interface every analytic layered model implements (:class:`Model`, :class:`ModelValue`,
:class:`ModelError`) and the coated-base description of two-interface stacks (:func:`coated_base`).

Conventions (same as :mod:`goniometer.optics` and ``docs/slices-format.md``):

* ``l`` is the unit light direction (pointing towards the light, ``l_z > 0``), shape (3,).
* ``v`` is an array of unit outgoing directions (pointing towards the viewer), shape (..., 3):
  upper hemisphere for the BRDF (``side="brdf"``), lower hemisphere for the BTDF (``side="btdf"``).
* Values are BSDF values **without** the cosine factor, in 1/sr, RGB on the last axis: (..., 3).
  BTDF values are flux based (``docs/slices-format.md``), i.e. the radiance BTDF when light exits into air.
* A BRDF is split into ``top`` -- the lobe of light reflected directly off the top interface
  (bounce order 1 in the simulator) -- and ``internal`` -- everything else. For a BTDF ``top``
  is zero and ``internal`` holds the whole BTDF.
* A stochastic model (one that estimates f, e.g. by Monte Carlo) may return its own estimator's
  standard errors beside its values (``ModelValue.stderr_top``, ``stderr_internal``); the
  comparison then reports the model's noise beside the reference's noise floor
  (``docs/models.md`` §3).
* A polarized model (``polarized = True``) also returns Mueller matrices
  (:meth:`Model.evaluate_mueller`): ``(..., 3, 4, 4)``, the whole BSDF (no top/internal split),
  1/sr without the cosine, mapping the Stokes vector of the light arriving along ``-l`` to that of
  the light leaving along ``v``, in the frames ``mueller_frames`` names (default ``"sp"``, the
  files' s/p frames; ``docs/polarization.md`` §1-2 and "Models on polarized files").
  ``M[..., 0, 0]`` is the intensity ``top + internal``.
* A model whose BSDF has Dirac lobes (a smooth interface's mirror reflection or refraction) gives
  them as :class:`DeltaLobe` objects (:meth:`Model.delta_lobes`, :meth:`Model.delta_lobes_mueller`) beside
  the finite part ``evaluate`` returns (where a Dirac lobe is 0, ``docs/models.md`` §1); the
  harness deposits each in the cell that holds its direction (``docs/models.md`` §3, "Delta lobes").

Writing a model, in a plugin package or behind ``--model python:MODULE:NAME``: ``docs/models.md``,
"Writing a model (plugins)".
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from goniometer.stack import Interface, Lambertian, Medium, Stack

SIDES = ("brdf", "btdf")


class ModelError(ValueError):
    """A model asked for something it cannot do (message names the model and the reason)."""


class ModelFailure(ModelError):
    """A model failed at what it claims to do: its ``support_reason`` or ``_evaluate`` raised, it
    returned something else than the values :meth:`Model.evaluate` promises, or non-finite values.
    ``model`` is its name, ``reason`` the failure in one line without the name; the message is
    ``"<model>: <reason>"``. Raised by :meth:`Model.reason` and :meth:`Model.evaluate` (the one place
    every harness, command and report calls a model through), it is that model's failure alone: a
    loop over models records it under ``failed`` and goes on with the others (``docs/models.md`` §3,
    "A model that fails"). A subclass of :class:`ModelError`, so that a caller that evaluates one
    model prints it as the one line it prints for any model error."""

    def __init__(self, model: str, reason: str) -> None:
        super().__init__(f"{model}: {reason}")
        self.model, self.reason = model, reason

    def __reduce__(self):
        return type(self), (self.model, self.reason)


def one_line(e: BaseException) -> str:
    """An exception's message on one line (its type's name when it has none)."""
    return " ".join(str(e).split()) or type(e).__name__


def failure(model: str, step: str, e: Exception) -> ModelFailure:
    """The :class:`ModelFailure` of ``model`` whose ``step`` (``"support_reason"``, ``"_evaluate"``)
    raised ``e``: a :class:`ModelFailure` as it is, a :class:`ModelError` by its own message (the
    model's words, without a leading ``"<model>: "``), anything else as
    ``"<step> raised <Type>: <message>"``."""
    if isinstance(e, ModelFailure):
        return e
    msg = one_line(e)
    if isinstance(e, ModelError):
        return ModelFailure(model, msg[len(model) + 2:] if msg.startswith(f"{model}: ") else msg)
    return ModelFailure(model, f"{step} raised {type(e).__name__}: {msg}")


@dataclass
class ModelValue:
    """Model output for one light direction: ``top`` and ``internal``, each (..., 3), 1/sr.

    ``stderr_top`` and ``stderr_internal`` (same shapes, 1/sr, or None for an exact part) are a
    stochastic model's own estimator standard errors of ``top`` and ``internal``, each direction's
    estimate independent of the others'. Deterministic models leave them None."""

    top: np.ndarray
    internal: np.ndarray
    stderr_top: np.ndarray | None = None
    stderr_internal: np.ndarray | None = None

    @property
    def total(self) -> np.ndarray:
        return self.top + self.internal

    @property
    def stderr(self) -> np.ndarray | None:
        """Standard error of ``total`` (the two parts' added in quadrature, as independent
        estimates), or None when the model is exact."""
        if self.stderr_top is None and self.stderr_internal is None:
            return None
        top = 0.0 if self.stderr_top is None else np.asarray(self.stderr_top)
        internal = 0.0 if self.stderr_internal is None else np.asarray(self.stderr_internal)
        return np.sqrt(np.square(top) + np.square(internal)) * np.ones_like(self.top)


@dataclass(frozen=True)
class DeltaLobe:
    """A Dirac lobe of a BSDF for one light direction: all its light leaves along the unit
    direction ``v`` (3,). ``value`` is the fraction of the incident flux it carries, the integral
    ``Int f |cos theta_v| dw`` over the lobe (Mitsuba's ``sample`` weight ``f |cos| / pdf`` of a
    delta component in importance mode): (3,) RGB for :meth:`Model.delta_lobes`, (3, 4, 4)
    (channel, row, column) Mueller matrices in the model's ``mueller_frames`` for
    :meth:`Model.delta_lobes_mueller`. ``part``: ``"top"`` (the reflection off the top interface)
    or ``"internal"``; Mueller lobes ignore it. A cell holding ``v`` then has the cell mean
    ``value / Omega(cell)`` (``docs/slices-format.md`` §4)."""

    v: np.ndarray
    value: np.ndarray
    part: str = "internal"


class Model(ABC):
    """An analytic layered BSDF model.

    Subclasses set ``name`` (the fixed CLI name), ``description``, ``sides`` (the sides it can
    evaluate) and implement :meth:`support_reason` and :meth:`_evaluate`.
    """

    name: str = ""
    description: str = ""
    sides: tuple[str, ...] = ("brdf",)
    #: whether the model handles anisotropic interfaces (roughness [alpha_x, alpha_y])
    anisotropic: bool = False
    #: whether the model handles scattering media (``scattering_albedo > 0``)
    scattering: bool = False
    #: whether the model handles thin films on interfaces (``Interface.film``, docs/spectral.md)
    films: bool = False
    #: evaluated only when named (``--model NAME``), not among "every model that applies": for
    #: models whose cost would dominate a report (e.g. the stochastic pbrt-v4 rows)
    on_request: bool = False
    #: a sentence every evaluation records under ``approximations`` (e.g. an adapter that does not
    #: read the stack); None for none
    approximation: str | None = None
    #: whether the model gives Mueller matrices (:meth:`evaluate_mueller`, ``docs/models.md``,
    #: "Polarized models"); a scalar model is judged on the intensity of a polarized file only
    polarized: bool = False
    #: the Stokes frames of :meth:`_evaluate_mueller`'s matrices, one of
    #: :data:`goniometer.grids.stokes.FRAMES`: ``"sp"`` (the files' s/p frames; at ``l = z`` the
    #: limit along the azimuth 0, at ``v = z`` along ``atan2(v_y, v_x)``), ``"mitsuba"`` (Mitsuba
    #: 3's ``stokes_basis``) or ``"plane"``; the harness converts them to the file's s/p frames
    mueller_frames: str = "sp"
    #: the model promises, on every stack without an anisotropic interface, the mirror symmetry
    #: about the plane of incidence: ``f(l, v) = f(l, v')`` with ``v' = (v_x, -v_y, v_z)`` whenever
    #: ``l_y = 0`` (both parts, ``top`` and ``internal``, and their standard errors if any), equal to
    #: rounding. A model whose value depends on ``l`` and ``v`` only through dot products with each
    #: other and with the normal (isotropic GGX, Fresnel, adding-doubling in cosines) has it; rotation
    #: invariance alone does not give it (a chiral microstructure is rotation invariant and breaks
    #: it), nor does a stochastic estimate whose random streams are keyed by the direction pair (its
    #: numbers at ``v`` and ``v'`` are two estimates). When it is True the harness evaluates the
    #: intensity on half of a grid's cells and fills the other half by mirroring
    #: (:mod:`models.compare.integrate`, ``docs/models.md`` §3, "Mirror symmetry"); False (the
    #: default, every plugin and adapter that does not declare it) evaluates every cell
    mirror_symmetric: bool = False

    @abstractmethod
    def support_reason(self, stack: Stack) -> str | None:
        """``None`` if the model can represent ``stack``, otherwise a one-line reason."""

    def reason(self, stack: Stack) -> str | None:
        """:meth:`support_reason` preceded by the checks every model shares (anisotropy, scattering,
        films). A ``support_reason`` that raises, or returns something else than None or a string,
        is the model's failure: :class:`ModelFailure`."""
        if not self.anisotropic and stack.is_anisotropic:
            return "isotropic interfaces only (this stack has an anisotropic roughness)"
        if not self.scattering:
            reason = scattering_reason(stack)
            if reason is not None:
                return reason
        if not self.films:
            reason = film_reason(stack)
            if reason is not None:
                return reason
        try:
            reason = self.support_reason(stack)
        except Exception as e:  # noqa: BLE001 -- any failure of the model's own code is its failure
            raise failure(self.name, "support_reason", e) from None
        if reason is not None and not isinstance(reason, str):
            raise ModelFailure(self.name, f"support_reason returned a {type(reason).__name__}, not None or a "
                                          f"one-line reason")
        return reason

    def on_request_reason(self) -> str:
        """Why the model is evaluated only when named (``on_request``)."""
        return "its cost would dominate a report"

    def on_request_note(self) -> str:
        """The ``skipped`` entry of an evaluation of "every model" that leaves an ``on_request`` model out."""
        return f"evaluated on request only (--model {self.name}): {self.on_request_reason()}"

    def cost_note(self, directions: int) -> str | None:
        """What evaluating ``directions`` direction pairs costs, in words, for a model whose cost
        stands out (a stochastic estimator: ``gonio evaluate`` says it before integrating, a report
        beside the material's time); None for the others (``docs/models.md`` §3, "Cost")."""
        return None

    def supports(self, stack: Stack) -> bool:
        return self.reason(stack) is None

    def _checked(self, stack, l, v, side: str, reason: str | None) -> tuple[np.ndarray, np.ndarray]:
        """``(l, v)`` as float64 arrays, after the checks every evaluation makes: the side is one the
        model has, ``reason`` (why it cannot evaluate ``stack``) is None, ``v`` has shape (..., 3);
        raises :class:`ModelError` otherwise."""
        if side not in self.sides:
            raise ModelError(f"{self.name}: cannot evaluate the {side.upper()} (it models {', '.join(self.sides)})")
        if reason is not None:
            raise ModelError(f"{self.name}: {reason}")
        l = np.asarray(l, dtype=np.float64).reshape(3)
        v = np.asarray(v, dtype=np.float64)
        if v.shape[-1] != 3:
            raise ModelError(f"{self.name}: v must have shape (..., 3), got {v.shape}")
        return l, v

    def evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str = "brdf") -> ModelValue:
        """f(l, v) split into top lobe and internal part; raises :class:`ModelError` if unsupported,
        :class:`ModelFailure` if ``_evaluate`` raises or returns anything but a :class:`ModelValue`
        whose ``top`` and ``internal`` have the shape ``v.shape[:-1] + (3,)``."""
        l, v = self._checked(stack, l, v, side, self.reason(stack))
        try:
            value = self._evaluate(stack, l, v, side)
        except Exception as e:  # noqa: BLE001 -- any failure of the model's own code is its failure
            raise failure(self.name, "_evaluate", e) from None
        _check_value(self.name, value, v.shape[:-1] + (3,))
        return value

    @abstractmethod
    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        """Evaluate for a supported stack (inputs already checked)."""

    def mueller_reason(self, stack: Stack) -> str | None:
        """None when the model gives Mueller matrices for ``stack`` (it supports the stack:
        :meth:`reason`), otherwise why it is judged on the intensity only (one line): a scalar model
        (``polarized = False``), or the polarized model's own :meth:`support_mueller_reason`. A
        ``support_mueller_reason`` that raises or returns something else than None or a string is
        the model's failure (:class:`ModelFailure`)."""
        if not self.polarized:
            return "a scalar model: it gives intensities, not Mueller matrices"
        try:
            reason = self.support_mueller_reason(stack)
        except Exception as e:  # noqa: BLE001 -- any failure of the model's own code is its failure
            raise failure(self.name, "support_mueller_reason", e) from None
        if reason is not None and not isinstance(reason, str):
            raise ModelFailure(self.name, f"support_mueller_reason returned a {type(reason).__name__}, not None "
                                          f"or a one-line reason")
        return reason

    def support_mueller_reason(self, stack: Stack) -> str | None:
        """A polarized model's own refusals of Mueller matrices for ``stack`` (None: it gives them)."""
        return None

    def mueller_note(self, stack: Stack) -> str | None:
        """How a polarized model computes its Mueller matrices for ``stack``, in words, when the
        reader needs it beside the numbers (e.g. a renderer's variant and wavelengths); None for none."""
        return None

    def evaluate_mueller(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str = "brdf") -> np.ndarray:
        """The Mueller matrices of the whole BSDF, ``v.shape[:-1] + (3, 4, 4)`` (channel, row,
        column), 1/sr without the cosine, in the frames :attr:`mueller_frames` (module docstring).
        Raises :class:`ModelError` when the model does not give them for ``stack``
        (:meth:`mueller_reason`) or cannot evaluate it, :class:`ModelFailure` when
        ``_evaluate_mueller`` raises or returns another shape or something else than real numbers."""
        reason = self.reason(stack) if side in self.sides else None
        l, v = self._checked(stack, l, v, side, reason if reason is not None else self.mueller_reason(stack))
        try:
            value = self._evaluate_mueller(stack, l, v, side)
            value = np.asarray(value)
        except Exception as e:  # noqa: BLE001 -- any failure of the model's own code is its failure
            raise failure(self.name, "_evaluate_mueller", e) from None
        want = v.shape[:-1] + (3, 4, 4)
        if value.shape != want:
            raise ModelFailure(self.name, f"_evaluate_mueller returned shape {value.shape}; expected {want} "
                                          f"(channel, row, column last)")
        if value.dtype.kind not in "biuf":
            raise ModelFailure(self.name, f"_evaluate_mueller returned dtype {value.dtype}, not real numbers")
        return value

    def _evaluate_mueller(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> np.ndarray:
        """A polarized model's Mueller matrices (:meth:`evaluate_mueller`; inputs already checked)."""
        raise ModelError(f"{self.name}: polarized = True but _evaluate_mueller is not implemented")

    def delta_lobes(self, stack: Stack, l: np.ndarray, side: str) -> list[DeltaLobe]:
        """The Dirac lobes of the BSDF lit from ``l`` that leave on ``side``, RGB values
        (:class:`DeltaLobe`); none by default. Called by the harness (:mod:`models.compare.integrate`)
        for a supported stack and side, beside :meth:`evaluate`, which leaves them out."""
        return []

    def delta_lobes_mueller(self, stack: Stack, l: np.ndarray, side: str) -> list[DeltaLobe]:
        """:meth:`delta_lobes` as Mueller matrices (3, 4, 4) in :attr:`mueller_frames`, for a model
        that gives Mueller matrices for ``stack``; none by default."""
        return []


def _check_value(name: str, value: object, want: tuple[int, ...]) -> None:
    """:class:`ModelFailure` unless ``value`` is a :class:`ModelValue` whose parts are real arrays of
    shape ``want``."""
    if not isinstance(value, ModelValue):
        raise ModelFailure(name, f"_evaluate returned a {type(value).__name__}, not a ModelValue")
    for part in ("top", "internal"):
        a = np.asarray(getattr(value, part))
        if a.shape != want:
            raise ModelFailure(name, f"_evaluate returned {part} of shape {a.shape}; expected {want} (RGB last)")
        if a.dtype.kind not in "biuf":
            raise ModelFailure(name, f"_evaluate returned {part} of dtype {a.dtype}, not real numbers")


def scattering_reason(stack: Stack) -> str | None:
    """Why a model whose media only absorb cannot represent ``stack`` (None if no medium scatters):
    the check every such model shares (:meth:`Model.reason`, Belcour's ``unsupported_reason``)."""
    for i, x in enumerate(stack.layers):
        if isinstance(x, Medium) and x.scatters:
            return (f"purely absorbing media only (layers[{i}] is a scattering medium, "
                    f"scattering_albedo = {list(x.scattering_albedo)})")
    return None


def film_reason(stack: Stack) -> str | None:
    """Why a model without thin films cannot represent ``stack`` (None if no interface carries a
    film of thickness > 0): the check every such model shares (:meth:`Model.reason`)."""
    for i, x in enumerate(stack.layers):
        film = getattr(x, "film", None)
        if isinstance(x, Interface) and film is not None and film.thickness_nm > 0.0:
            return f"no thin films (layers[{i}] carries a film of {film.thickness_nm:g} nm)"
    return None


# ---------------------------------------------------------------------- stack descriptions

@dataclass(frozen=True)
class CoatedBase:
    """The two-interface structure of Bati 2019's database: a dielectric coat over a base.

    ``alpha0``/``eta0``: top interface roughness and (absolute) coat index; ``tau``: optical
    depth of the coat medium (RGB, zeros if none); ``base``: "lambertian", "conductor" or
    "dielectric"; ``rho`` (Lambertian), ``alpha1``/``eta1``/``kappa1`` (conductor or dielectric
    base interface, absolute index of what lies below it).
    """

    alpha0: float
    eta0: float
    tau: np.ndarray
    base: str
    rho: np.ndarray | None = None
    alpha1: float | None = None
    eta1: np.ndarray | None = None
    kappa1: np.ndarray | None = None


def coated_base(stack: Stack) -> CoatedBase | None:
    """Describe ``stack`` as [dielectric interface, (medium), base] or return None."""
    layers = list(stack.layers)
    if len(layers) < 2 or not isinstance(layers[0], Interface) or layers[0].is_conductor:
        return None
    top = layers[0]
    rest = layers[1:]
    tau = np.zeros(3)
    if isinstance(rest[0], Medium):
        tau = np.asarray(rest[0].optical_depth, dtype=float)
        rest = rest[1:]
    if len(rest) != 1:
        return None
    b = rest[0]
    if isinstance(b, Lambertian):
        return CoatedBase(top.roughness, top.ior[0], tau, "lambertian", rho=np.asarray(b.albedo, dtype=float))
    if isinstance(b, Interface):
        kind = "conductor" if b.is_conductor else "dielectric"
        return CoatedBase(top.roughness, top.ior[0], tau, kind, alpha1=b.roughness,
                          eta1=np.asarray(b.ior, dtype=float), kappa1=np.asarray(b.extinction, dtype=float))
    return None


def require_slices(reference) -> None:
    """Raise :class:`ModelError` unless ``reference`` holds classic or half slices: a file recorded
    on the RGL grid (``docs/rgl-format.md``) is for ``gonio export --format rgl``, its cells are the
    format's sample space, not directions a model can be integrated over."""
    if reference.settings.parametrization == "rgl":
        raise ModelError("the file is recorded on the RGL grid (for gonio export --format rgl); models are judged "
                         "on classic or half slices (simulate with --parametrization classic or half)")
