"""models: analytic layered BSDF models, their tables, the comparison harness and the inverse
method (the model floor), with the application (``models.commands``, ``models.report``) on top.

The public face, for notebooks and scripts::

    import models
    models.list_models()                        # name -> model (analytic, then fitted classes)
    ev = models.evaluate(result, ["ww09", "belcour-fwd"])   # result: goniometer.read(...) or simulate(...)
    ev.errors["belcour-fwd"]["total"]["rmse_mean"]
    models.invert([models.parse_lobe("R=0.04 sigma=0.01 layers=1")])

Conventions and the model list: ``docs/models.md``. Names are loaded on first use, so
``import models`` (and ``gonio --help``) imports no model.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

#: public name -> (module, attribute)
_EXPORTS = {
    # the models
    "Model": ("models.base", "Model"), "ModelValue": ("models.base", "ModelValue"),
    "ModelError": ("models.base", "ModelError"), "ModelFailure": ("models.base", "ModelFailure"),
    "list_models": ("models.registry", "catalogue"), "get_model": ("models.registry", "get"),
    "FITTED": ("models.registry", "FITTED"),
    # the comparison harness
    "evaluate": ("models.evaluation", "evaluate"), "Evaluation": ("models.evaluation", "Evaluation"),
    "integrate": ("models.compare.integrate", "integrate"),
    # white-furnace / directional-albedo tables (docs/furnace.md)
    "run_furnace": ("models.furnace", "run_furnace"), "furnace_settings": ("models.furnace", "furnace_settings"),
    "FurnaceResult": ("models.furnace", "FurnaceResult"),
    "directional_albedo": ("models.compare.albedo", "directional_albedo"),
    # fitted models
    "fit": ("models.fitted", "fit"),
    # the inverse method (Bati 2021)
    "Lobe": ("models.inverse", "Lobe"), "parse_lobe": ("models.inverse", "parse_lobe"),
    "invert": ("models.inverse", "invert"), "InverseError": ("models.inverse", "InverseError"),
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    target = _EXPORTS.get(name)
    if target is None:
        raise AttributeError(f"module 'models' has no attribute {name!r}")
    value = getattr(import_module(target[0]), target[1])
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
