"""Every name a public face lists in ``__all__`` resolves: ``goniometer``, ``models`` and each of
their subpackages (docs/architecture.md, public faces), and the examples of the faces' docstrings
name only names that exist."""

from __future__ import annotations

import importlib
import pkgutil
import re

import pytest

import goniometer
import models


def _packages() -> list[str]:
    names = []
    for root in (goniometer, models):
        names.append(root.__name__)
        for info in pkgutil.walk_packages(root.__path__, prefix=root.__name__ + "."):
            if info.ispkg:
                names.append(info.name)
    return names


PACKAGES = _packages()


def test_the_walk_found_the_subpackages():
    assert {"goniometer.kernel", "goniometer.cli", "models.belcour", "models.inverse", "models.report",
            "models.production"} <= set(PACKAGES)


@pytest.mark.parametrize("name", PACKAGES)
def test_every_name_in_all_resolves(name):
    module = importlib.import_module(name)
    assert hasattr(module, "__all__"), f"{name} has no __all__"
    missing = []
    for attr in module.__all__:
        try:
            getattr(module, attr)
        except AttributeError:
            try:  # a submodule listed by name
                importlib.import_module(f"{name}.{attr}")
            except ImportError:
                missing.append(attr)
    assert not missing, f"{name}.__all__ lists names that do not resolve: {missing}"


@pytest.mark.parametrize("root", [goniometer, models])
def test_the_faces_docstring_examples_use_existing_names(root):
    used = set(re.findall(rf"\b{'g' if root is goniometer else 'models'}\.([A-Za-z_]\w*)\(", root.__doc__))
    assert used, "the docstring shows no example"
    assert used <= set(root.__all__), sorted(used - set(root.__all__))


def test_models_face_docstring_example_runs():
    lobe = models.parse_lobe("R=0.04 sigma=0.01 layers=1")
    stack = models.invert([lobe])
    assert stack.interfaces and models.fit is models.fitted.fit


@pytest.mark.parametrize("root", [goniometer, models])
def test_the_architecture_doc_lists_each_face(root):
    """README points to docs/architecture.md for the public names: it lists exactly the faces' names."""
    from pathlib import Path
    doc = (Path(__file__).resolve().parents[1] / "docs" / "architecture.md").read_text()
    section = doc.split("## Public faces", 1)[1]
    entry = section.split(f"- `{root.__name__}`:", 1)[1].split("\n- ", 1)[0]
    listed = set(re.findall(r"`(\w+)`", entry))
    assert listed == set(root.__all__), (sorted(set(root.__all__) - listed), sorted(listed - set(root.__all__)))
