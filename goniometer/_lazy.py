"""Package faces that load their names on first use (``goniometer``'s and its sub-packages'), so
that importing a package imports none of its modules until a name is asked for."""

from __future__ import annotations

from importlib import import_module
from typing import Any, Callable, Mapping


def lazy_face(package: str, exports: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for ``package`` whose public names ``exports`` maps to the
    modules that define them; a name is imported on first use and kept in the package's globals."""

    def __getattr__(name: str) -> Any:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(module), name)
        setattr(import_module(package), name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(import_module(package))) | set(exports))

    return __getattr__, __dir__
