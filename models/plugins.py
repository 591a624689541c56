"""Model plugins: :class:`models.base.Model` classes that installed distributions register in the
entry-point group ``goniometer.models`` (``docs/models.md``, "Writing a model (plugins)").

The contract of an entry point: its value ``module:Class`` names a :class:`~models.base.Model`
subclass that is built with no arguments; the model's name is the instance's ``name`` (by
convention also the entry point's name)::

    [project.entry-points."goniometer.models"]
    coated-diffuse = "example_plugin:CoatedDiffuse"

:func:`installed` scans the group once per process (``functools.lru_cache``; :func:`clear_cache`
starts afresh, for tests) and returns one :class:`Plugin` per usable entry point, in entry-point
name order; :mod:`models.registry` lists them after the built-in models and refuses a name clash
(:class:`PluginError`). An entry point that fails to import, does not name a Model subclass, fails
to construct or gives no usable name is left out with **one warning line** on stderr, once per scan:
the message goes to the logger ``models.plugins``, which, when the program configured no logging
(``gonio``), Python's last-resort handler prints as the bare message, one line.

:func:`module_key` hashes the sources of a plugin's (or an adapter's) module, so that a report's
cache of model evaluations (``docs/report.md``) is keyed by code outside ``goniometer`` and
``models`` too.
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
from dataclasses import dataclass
from functools import lru_cache
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path

from models.base import Model, ModelError, one_line

#: the entry-point group through which distributions contribute models
GROUP = "goniometer.models"
#: characters a model name may not hold (``:`` starts an adapter spec, ``python:...``, ``mitsuba:...``)
RESERVED = (":",)

logger = logging.getLogger(__name__)

__all__ = ["GROUP", "Plugin", "PluginError", "clear_cache", "installed", "module_key"]


class PluginError(ModelError):
    """The registry cannot be built: two registrations of one model name (the message names both
    distributions). The CLI prints it as one line and exits with status 2."""


@dataclass(frozen=True)
class Plugin:
    """One usable entry point of :data:`GROUP`: where it comes from and the class it names."""

    entry_point: str              # the entry point's name
    value: str                    # "module:Class"
    distribution: str             # the distribution's name ("" when the finder gives none)
    version: str
    model_class: type[Model]
    name: str                     # the model's name (its instance's ``name``)

    @property
    def source(self) -> str:
        """``"<distribution> <version>"``: the ``source`` column of ``gonio models``."""
        return f"{self.distribution} {self.version}".strip() or "unknown distribution"

    @property
    def module(self) -> str:
        return self.value.partition(":")[0].strip()

    def build(self) -> Model:
        """A fresh instance (the registry builds its models on demand, as it does the built-ins)."""
        return self.model_class()


def _where(ep: EntryPoint) -> tuple[str, str]:
    dist = getattr(ep, "dist", None)
    if dist is None:
        return "", ""
    return str(dist.metadata.get("Name") or ""), str(dist.version or "")


def _load(ep: EntryPoint) -> Plugin | str:
    """The plugin of ``ep``, or why it cannot be used (one line)."""
    dist, version = _where(ep)
    try:
        cls = ep.load()
    except Exception as e:  # noqa: BLE001 -- any failure of a third party's import: one warning
        return f"cannot import {ep.value}: {type(e).__name__}: {one_line(e)}"
    if not (isinstance(cls, type) and issubclass(cls, Model)):
        return f"{ep.value} is not a models.base.Model subclass (it is a {type(cls).__name__})"
    try:
        model = cls()
    except Exception as e:  # noqa: BLE001
        return f"{ep.value}() failed: {type(e).__name__}: {one_line(e)}"
    name = getattr(model, "name", "")
    if not isinstance(name, str) or not name or any(c in name for c in RESERVED) or name != name.strip():
        return f"{ep.value} has no usable name ({name!r}: a non-empty name without ':' or surrounding spaces)"
    return Plugin(ep.name, ep.value, dist, version, cls, name)


@lru_cache(maxsize=1)
def installed() -> tuple[Plugin, ...]:
    """The usable model plugins, in entry-point name order (scanned once per process: see the module
    docstring; each unusable one is one warning line)."""
    found = []
    for ep in sorted(entry_points(group=GROUP), key=lambda ep: (ep.name, ep.value)):
        got = _load(ep)
        if isinstance(got, Plugin):
            found.append(got)
            continue
        dist, version = _where(ep)
        origin = f"{dist} {version}".strip() or "unknown distribution"
        logger.warning("model plugin %r (%s, entry-point group %s) left out: %s", ep.name, origin, GROUP, got)
    return tuple(found)


def clear_cache() -> None:
    """Forget the scan (tests that change ``sys.path`` or the installed distributions call it)."""
    installed.cache_clear()


def module_key(module: str) -> str:
    """Hash of the sources of ``module``'s top-level package (every ``.py`` below it) or, for a
    top-level single-file module, of that file; found without importing it. A module whose file
    cannot be found is hashed by its name alone."""
    head = module.split(".")[0]
    h = hashlib.sha256(head.encode())
    try:
        spec = importlib.util.find_spec(head)
    except (ImportError, ValueError):
        spec = None
    files: list[Path] = []
    if spec is not None and spec.submodule_search_locations:
        for root in spec.submodule_search_locations:
            files += sorted(Path(root).rglob("*.py"))
    elif spec is not None and spec.origin and Path(spec.origin).is_file():
        files = [Path(spec.origin)]
    for p in files:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:16]
