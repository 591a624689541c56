"""The fitted models ``hp15-fit``, ``ggx1-fit``, ``ggx2-fit``: a :class:`models.base.Model` built from
a family's parameter vector (:class:`FittedModel`). The whole BRDF is returned in
``ModelValue.internal`` (``top`` is 0: a fit has no top-lobe/internal split); any stack is accepted."""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from goniometer.stack import Stack
from models.base import Model, ModelError, ModelValue
from models.fitted.family import INV_PI, Family
from models.fitted.ggx import GGXFamily
from models.fitted.hp15 import HP15Family
from models.fitted.samples import Samples


FAMILIES: dict[str, Callable[[], Family]] = {
    "hp15": HP15Family,
    "ggx1": lambda: GGXFamily(1),
    "ggx2": lambda: GGXFamily(2),
}


class FittedModel(Model):
    """A fitted BRDF, constructed from its natural parameter vector (order of ``param_names``).

    Stack-agnostic (``support_reason`` is always None): the parameters came from one file.
    The whole BRDF is returned in ``ModelValue.internal``; ``top`` is 0 (no split in a fit).
    """

    sides = ("brdf",)
    kind: str = ""
    #: a fit describes the file, whatever the stack: anisotropic materials are fitted like others
    anisotropic = True
    #: likewise for scattering media: the fit never looks at the stack
    scattering = True

    def __init__(self, x: Sequence[float] | np.ndarray) -> None:
        self.family = FAMILIES[self.kind]()
        x = np.array(x, dtype=np.float64).reshape(-1)
        reason = self.family.check(x)
        if reason is not None:
            raise ModelError(f"{self.name}: {reason}")
        self.x = x
        self._table = self.family.table(x[self.family.slices()["p"]][0]) if self.kind == "hp15" else None

    @classmethod
    def from_params(cls, params: dict) -> "FittedModel":
        """Build from a ``{name: value or RGB list}`` dict (as :attr:`params` / ``FitResult.params``)."""
        return cls(FAMILIES[cls.kind]().from_dict(params))

    @classmethod
    def param_names(cls) -> list[str]:
        return [s.name for s in FAMILIES[cls.kind]().specs]

    @property
    def params(self) -> dict[str, float | list[float]]:
        return self.family.to_dict(self.x)

    def support_reason(self, stack: Stack) -> str | None:
        return None

    def _evaluate(self, stack: Stack, l: np.ndarray, v: np.ndarray, side: str) -> ModelValue:
        smp = Samples.directions(l, v)
        if self.kind == "hp15":
            f = self._hp_evaluate(smp)
        else:
            f = self.family.evaluate(self.x, smp)
        f = np.where(smp.valid[:, None], f, 0.0).reshape(v.shape[:-1] + (3,))
        return ModelValue(np.zeros_like(f), f)

    def _hp_evaluate(self, smp: Samples) -> np.ndarray:
        s = self.family.slices()
        x = self.x
        A, B, R = self.family.pieces(x[s["sigma"]][0], x[s["p"]][0], x[s["a"]][0], smp, self._table)
        ks, f0, kw = x[s["ks"]], x[s["F0"]], x[s["kw"]]
        return x[s["kd"]][None, :] * INV_PI + ks * (A[:, None] * f0 + B[:, None]) + R * kw


class HP15Fit(FittedModel):
    """Holzschuch & Pacanowski 2015 (eq. 24-27): diffuse + Cook-Torrance with their distribution + diffraction."""

    name = "hp15-fit"
    kind = "hp15"
    description = "Holzschuch-Pacanowski 2015 fitted: diffuse + exponential-power Cook-Torrance + diffraction (15 parameters)"


class GGX1Fit(FittedModel):
    """Lambertian + one GGX lobe with a Schlick Fresnel shape, fitted (8 parameters)."""

    name = "ggx1-fit"
    kind = "ggx1"
    description = "fitted Lambertian + one GGX lobe (RGB ks, Schlick F0), 8 parameters"


class GGX2Fit(FittedModel):
    """Lambertian + two GGX lobes with Schlick Fresnel shapes, fitted (13 parameters)."""

    name = "ggx2-fit"
    kind = "ggx2"
    description = "fitted Lambertian + two GGX lobes (RGB ks, Schlick F0), 13 parameters"


MODELS: dict[str, type[FittedModel]] = {"hp15": HP15Fit, "ggx1": GGX1Fit, "ggx2": GGX2Fit}


def model_class(kind: str) -> type[FittedModel]:
    """The model class of ``kind`` ("hp15", "ggx1", "ggx2" or their "-fit" names)."""
    k = kind[:-4] if kind.endswith("-fit") else kind
    if k not in MODELS:
        raise ModelError(f"unknown fitted model {kind!r} (known: {', '.join(MODELS)})")
    return MODELS[k]

