"""Fixtures shared by the model tests."""

from __future__ import annotations

import pytest

from models.tables import multilayer as mt
from models.tables import belcour as tables


@pytest.fixture
def tiny_multilayer_grid(monkeypatch):
    """A tiny multilayer-lut grid, so that cache tests build in milliseconds (its lookups are then
    far from the quadrature: only file handling can be tested with it)."""
    for name, value in (("N_ALPHA", 3), ("N_MU_UP", 3), ("N_ETA_UP", 2), ("N_ETA_DOWN", 2),
                        ("N_MU_LOWER", 2), ("N_MU_UPPER", 2), ("QUAD_Z", 2), ("QUAD_PHI", 2)):
        monkeypatch.setattr(mt, name, value)
    mt._load_cached.cache_clear()
    yield
    mt._load_cached.cache_clear()
    tables._load_cached.cache_clear()
