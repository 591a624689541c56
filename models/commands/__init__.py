"""The ``models`` plugin of ``gonio``: the commands of the model floor (application).

``pyproject.toml`` declares :func:`register` in the entry-point group ``goniometer.commands``;
the host (:mod:`goniometer.cli`) calls it. Nothing below the application imports this package.

Every command of this plugin runs under :func:`registry_errors`: a model registry that cannot be
built (two registrations of one model name, :class:`models.plugins.PluginError`) is one line
``gonio: error: ...`` and exit status 2, whichever command asked for the models.
"""

from __future__ import annotations

import argparse
import functools
from typing import Callable

from models.commands import evaluate, furnace, inverse, lut, production, render, report, tables

__all__ = ["register"]


def register(sub) -> None:
    """Add the models' commands to the ``gonio`` sub-command parser."""
    before = set(sub.choices)
    report.register(sub)
    evaluate.register(sub)
    inverse.register(sub)
    tables.register(sub)
    furnace.register(sub)
    production.register(sub)
    render.register(sub)
    lut.register(sub)
    for name in set(sub.choices) - before:
        parser = sub.choices[name]
        func = parser.get_default("func")
        if func is not None:
            parser.set_defaults(func=registry_errors(func))


def registry_errors(func: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """``func`` with a :class:`models.plugins.PluginError` turned into a usage error (one line, exit 2).
    The import happens when the command runs, so ``gonio --help`` still imports no model."""
    @functools.wraps(func)
    def run(args: argparse.Namespace) -> int:
        from goniometer.cli.common import usage_errors
        from models.plugins import PluginError
        with usage_errors(PluginError):
            return func(args)
    return run
