"""The ``models`` plugin of ``gonio``: the commands of the model floor (application).

``pyproject.toml`` declares :func:`register` in the entry-point group ``goniometer.commands``;
the host (:mod:`goniometer.cli`) calls it. Nothing below the application imports this package.
"""

from __future__ import annotations

from models.commands import evaluate, furnace, inverse, production, render, report, tables

__all__ = ["register"]


def register(sub) -> None:
    """Add the models' commands to the ``gonio`` sub-command parser."""
    report.register(sub)
    evaluate.register(sub)
    inverse.register(sub)
    tables.register(sub)
    furnace.register(sub)
    production.register(sub)
    render.register(sub)
