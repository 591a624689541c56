"""The fixed model names and where they live (built on demand; no global state)."""

from __future__ import annotations

from models.base import Model, ModelError


def all_models() -> dict[str, Model]:
    """Every analytic model of the harness, by its fixed name, in display order."""
    from models.belcour import BelcourAniso, BelcourBati19, BelcourBTDF, BelcourForward, BelcourSymmetric
    from models.multilayer_lut import MultilayerLUT
    from models.weidlich_wilkie import Elek10, WW09, WWBati19
    found: list[Model] = [WW09(), Elek10(), WWBati19(), BelcourForward(), BelcourSymmetric(), BelcourBati19(),
                          BelcourBTDF(), BelcourAniso(), MultilayerLUT()]
    # production coat models (issue 13): OpenPBR and Standard Surface coats, Kulla-Conty GGX interface,
    # Mitsuba 3's own BSDFs
    from models.production import (GGXKullaConty, MitsubaPrincipled, MitsubaRoughPlastic, OpenPBRCoat,
                                   StandardSurfaceCoat)
    found += [OpenPBRCoat(), StandardSurfaceCoat(), GGXKullaConty(), MitsubaRoughPlastic(), MitsubaPrincipled()]
    found += __import__("models.pbrt_layered", fromlist=["built_in_models"]).built_in_models()  # pbrt-v4 LayeredBxDF
    return {m.name: m for m in found}


#: models fitted to a file on request (``gonio fit``, ``gonio evaluate --model NAME``)
FITTED = ("hp15-fit", "ggx1-fit", "ggx2-fit")


def fitted_models() -> dict[str, type[Model]]:
    """The fitted model classes by name (they need parameters: build them with a fit)."""
    from models.fitted import GGX1Fit, GGX2Fit, HP15Fit
    return {c.name: c for c in (HP15Fit, GGX1Fit, GGX2Fit)}


def catalogue() -> dict[str, Model | type[Model]]:
    """Every name the harness knows: the analytic models, then the fitted ones."""
    return {**all_models(), **fitted_models()}


def get(name: str) -> Model:
    """The model called ``name``; :class:`ModelError` naming the known ones otherwise."""
    models = all_models()
    if name not in models:
        raise ModelError(f"unknown model {name!r} (known: {', '.join(models)})")
    return models[name]
