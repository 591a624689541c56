"""The switches of the Belcour models (:class:`BelcourOptions`); their meaning and defaults are
stated in ``docs/belcour.md`` ("Choices")."""

from __future__ import annotations

from dataclasses import dataclass

#: cosine nodes at which direction-dependent statistics are tabulated (``docs/belcour.md``, "Speed")
DIRECTION_GRID = 2048


@dataclass(frozen=True)
class BelcourOptions:
    """The switches of the Belcour models (meaning and defaults: ``docs/belcour.md``, "Choices")."""

    incident: str = "light"
    use_tir: bool = False
    transmission_scale: str = "normal"
    per_channel: bool = True
    height_correlated: bool = False
    fgd_source: str = "material"
    transmitted_jacobian: str = "reference"
    cache_dir: str | None = None
    direction_grid: int = DIRECTION_GRID

    def __post_init__(self) -> None:
        if self.incident not in ("light", "view"):
            raise ValueError(f"incident must be 'light' or 'view', got {self.incident!r}")
        if self.transmission_scale not in ("normal", "angular"):
            raise ValueError(f"transmission_scale must be 'normal' or 'angular', got {self.transmission_scale!r}")
        if self.direction_grid != 0 and self.direction_grid < 2:
            raise ValueError(f"direction_grid must be 0 or >= 2, got {self.direction_grid!r}")
        if self.transmitted_jacobian not in ("reference", "consistent"):
            raise ValueError(f"transmitted_jacobian must be 'reference' or 'consistent', "
                             f"got {self.transmitted_jacobian!r}")
        if self.fgd_source not in ("material", "table"):
            raise ValueError(f"fgd_source must be 'material' or 'table', got {self.fgd_source!r}")


def resolve_options(options: BelcourOptions | None, kwargs: dict, cls: type = BelcourOptions) -> BelcourOptions:
    """``options`` if given, else ``cls(**kwargs)`` (the calling convention of :func:`stack_statistics`:
    an options object *or* keyword options)."""
    if options is not None and kwargs:
        raise TypeError("give either an options object or keyword options, not both")
    return options if options is not None else cls(**kwargs)
