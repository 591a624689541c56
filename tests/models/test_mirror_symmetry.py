"""The mirror symmetry of the integration (``docs/models.md`` §3, "Mirror symmetry"): a model that
declares ``Model.mirror_symmetric`` is evaluated on half of a grid's cell columns when the light has
``l_y = 0`` and the stack is isotropic, the other columns taken from their mirrors
(``models.compare.integrate.mirrored``, ``models.compare.cells.mirror_half`` and ``cell_sums``).

Every built-in model that declares it gives, on small classic and half grids (an odd ``n_phi``
too) and the first three stacks it supports (coated metal, plastic, conductor, clear coats,
dielectric, filmed interfaces, slab; BRDF and BTDF), the cell values of the full evaluation to
1e-12 relative; a chiral
toy model that declares it wrongly is caught by the same comparison; an anisotropic stack, a light
off the plane ``l_y = 0``, the stochastic pbrt-layered rows, the fitted models and the adapters are
evaluated on every cell."""

from __future__ import annotations

import numpy as np
import pytest

from goniometer.grids.slice_grid import SliceGrid, light_direction
from goniometer.stack import Film, Interface, Lambertian, Medium, Stack
from models import adapters, registry
from models.adapters import FunctionModel, MitsubaFileModel
from models.base import Model, ModelValue
from models.compare import cells
from models.compare.integrate import integrate_slice_parts, mirrored

CONDUCTOR = dict(ior=(0.2, 0.9, 1.1), extinction=(3.9, 2.4, 2.2))
FILM = Film(300.0, (1.8,) * 3)

#: the stacks every flagged model is tried on: the first MAX_STACKS it supports, in this order (the
#: slab last: its Belcour statistics take seconds, and belcour-btdf has no other)
STACKS = {
    "coated metal": Stack("cm", (Interface(0.2, (1.5,) * 3), Medium((0.05, 0.1, 0.4)), Interface(0.3, **CONDUCTOR))),
    "plastic": Stack("p", (Interface(0.1, (1.5,) * 3), Medium((0.2,) * 3), Lambertian((0.2, 0.5, 0.8)))),
    "conductor": Stack("c", (Interface(0.3, **CONDUCTOR),)),
    "clear plastic": Stack("cp", (Interface(0.1, (1.5,) * 3), Lambertian((0.2, 0.5, 0.8)))),
    "clear metal": Stack("cl", (Interface(0.1, (1.5,) * 3), Interface(0.3, **CONDUCTOR))),
    "dielectric": Stack("d", (Interface(0.2, (1.5,) * 3),)),
    "filmed conductor": Stack("fc", (Interface(0.2, **CONDUCTOR, film=FILM),)),
    "filmed dielectric": Stack("fd", (Interface(0.2, (1.5,) * 3, film=FILM),)),
    "slab": Stack("s", (Interface(0.15, (1.5,) * 3), Medium((0.1,) * 3), Interface(0.25, (1.0,) * 3))),
}
MAX_STACKS = 3
ANISOTROPIC = Stack("a", (Interface(0.1, (1.5,) * 3), Medium((0.2,) * 3),
                          Interface(0.1, roughness_y=0.4, rotation_deg=30.0, **CONDUCTOR)))

#: small grids: classic and half with an even n_phi, classic with an odd one (a self-mirrored column)
GRIDS = (("classic", 6, 14), ("half", 6, 14), ("classic", 5, 9))
THETAS = (0.0, 40.0, 75.0)
S = 3
REL = 1e-12


def grid_of(param: str, nt: int, nph: int, side: str) -> SliceGrid:
    return SliceGrid(param, nt, nph, "reflection" if side == "brdf" else "transmission")


def disagreement(model: Model, stack: Stack, grid: SliceGrid, light: np.ndarray, s: int = S) -> float:
    """The largest relative difference, over the cells, between ``model``'s mirrored integration and
    its full one (top, internal and any standard errors); asserts that the mirrored path was taken."""
    flag = model.mirror_symmetric
    try:
        model.mirror_symmetric = False
        full = integrate_slice_parts(model, stack, grid, light, s)
        model.mirror_symmetric = True
        assert mirrored(model, stack, grid, light)
        half = integrate_slice_parts(model, stack, grid, light, s)
    finally:
        model.mirror_symmetric = flag
    worst = 0.0
    for a, b in zip(full, half):
        assert (a is None) == (b is None)
        if a is None:
            continue
        scale = np.maximum(np.abs(a), 1e-300)
        worst = max(worst, float(np.max(np.abs(a - b) / scale)))
    return worst


def flagged_built_in() -> list[str]:
    sources = registry.sources()
    return [n for n, m in registry.all_models().items() if sources[n] == registry.BUILT_IN and m.mirror_symmetric]


def flagged() -> list[str]:
    """Every registered model that declares the symmetry: the built-in ones and installed plugins
    (the example plugin ``coated-diffuse`` where ``make setup`` installed it)."""
    return [n for n, m in registry.all_models().items() if m.mirror_symmetric]


def test_the_flagged_built_in_models():
    """The deterministic analytic models declare it; the stochastic, fitted and adapted ones do not."""
    assert set(flagged_built_in()) == {
        "ww09", "elek10", "ww-bati19", "belcour-fwd", "belcour-sym", "belcour-bati19", "belcour-btdf",
        "belcour-aniso", "multilayer-lut", "openpbr-coat", "standard-surface-coat", "ggx-kulla-conty",
        "mitsuba-roughplastic", "mitsuba-principled", "belcour-iridescence", "openpbr-thin-film"}
    models = registry.all_models()
    assert [n for n in models if n.startswith("pbrt-layered") and models[n].mirror_symmetric] == []
    assert not any(c.mirror_symmetric for c in registry.fitted_models().values())
    assert FunctionModel.mirror_symmetric is False and MitsubaFileModel.mirror_symmetric is False
    assert Model.mirror_symmetric is False


@pytest.mark.parametrize("name", flagged())
def test_a_flagged_model_mirrored_is_the_full_evaluation(name):
    model = registry.get(name)
    tried = []
    for label, stack in [(k, x) for k, x in STACKS.items() if model.reason(x) is None][:MAX_STACKS]:
        for side in model.sides:
            for param, nt, nph in GRIDS:
                grid = grid_of(param, nt, nph, side)
                for theta in THETAS:
                    d = disagreement(model, stack, grid, light_direction(theta), S)
                    assert d <= REL, (label, side, param, nph, theta, d)
            tried.append((label, side))
    assert tried, f"{name} supports none of the test stacks"


class Chiral(Model):
    """Rotation invariant but not mirror symmetric: ``1 + (l x v)_z / 2``, which changes sign with
    ``v_y`` when ``l_y = 0``. Declared mirror symmetric, wrongly."""

    name = "chiral"
    sides = ("brdf", "btdf")
    mirror_symmetric = True

    def support_reason(self, stack):
        return None

    def _evaluate(self, stack, l, v, side):
        f = 1.0 + 0.5 * (l[0] * v[..., 1] - l[1] * v[..., 0])
        out = np.repeat(f[..., None], 3, axis=-1)
        return ModelValue(0.1 * out, out, stderr_internal=0.01 * out)


class Symmetric(Chiral):
    """A symmetric toy model with standard errors: ``1 + (l.v)^2 / 2``."""

    name = "symmetric"

    def _evaluate(self, stack, l, v, side):
        f = 1.0 + 0.5 * (v @ l) ** 2
        out = np.repeat(f[..., None], 3, axis=-1)
        return ModelValue(0.1 * out, out, stderr_internal=0.01 * out)


@pytest.mark.parametrize("param", ["classic", "half"])
def test_the_comparison_catches_a_wrongly_flagged_model(param):
    stack = STACKS["plastic"]
    grid = SliceGrid(param, 6, 14)
    assert disagreement(Chiral(), stack, grid, light_direction(40.0)) > 0.05
    # a symmetric one agrees, standard errors included
    assert disagreement(Symmetric(), stack, grid, light_direction(40.0)) <= REL


class Counting(Model):
    """Records how many directions each evaluation gets."""

    name = "counting"
    sides = ("brdf", "btdf")
    anisotropic = True

    def __init__(self, flag: bool) -> None:
        self.mirror_symmetric = flag
        self.calls: list[int] = []

    def support_reason(self, stack):
        return None

    def _evaluate(self, stack, l, v, side):
        self.calls.append(v.shape[0])
        out = np.ones(v.shape[:-1] + (3,))
        return ModelValue(out, out)


def _evaluated(model: Model, stack: Stack, grid: SliceGrid, light: np.ndarray) -> int:
    model.calls.clear()
    integrate_slice_parts(model, stack, grid, light, S)
    return sum(model.calls)


def test_only_a_declared_model_on_an_isotropic_stack_in_the_plane_is_mirrored():
    grid, odd = SliceGrid("classic", 6, 14), SliceGrid("half", 5, 9, "transmission")
    full, half = 6 * 14 * S * S, 6 * 7 * S * S
    l = light_direction(40.0)
    stack = STACKS["plastic"]
    assert _evaluated(Counting(True), stack, grid, l) == half
    assert _evaluated(Counting(True), stack, odd, l) == 5 * 5 * S * S          # columns 0-4 of 9: 4 is its own mirror
    assert _evaluated(Counting(False), stack, grid, l) == full                 # an unflagged plugin
    assert _evaluated(Counting(True), ANISOTROPIC, grid, l) == full            # an anisotropic stack
    assert _evaluated(Counting(True), stack, grid, light_direction(40.0, 180.0)) == full   # l_y = sin(pi) != 0
    assert _evaluated(Counting(True), stack, grid, light_direction(40.0, 30.0)) == full
    assert cells.mirror_half(SliceGrid("rgl", 6, 14), l, S) is None
    # a flagged model that handles anisotropy is mirrored on isotropic stacks only
    aniso = registry.get("belcour-aniso")
    assert aniso.reason(ANISOTROPIC) is None and not mirrored(aniso, ANISOTROPIC, grid, l)
    assert mirrored(aniso, stack, grid, l)
    # the stochastic rows and a python: function are not
    for name in [n for n in registry.all_models() if n.startswith("pbrt-layered")]:
        assert not mirrored(registry.get(name), stack, grid, l), name
    function = adapters.resolve("python:tests.models.test_mirror_symmetry:constant_function")
    assert isinstance(function, FunctionModel) and not mirrored(function, stack, grid, l)


def constant_function(l, v, stack):
    """A ``python:`` function model (test of the adapter)."""
    return np.ones(v.shape[:-1] + (3,))


@pytest.mark.parametrize("param", ["classic", "half"])
@pytest.mark.parametrize("side", ["reflection", "transmission"])
@pytest.mark.parametrize("nph", [14, 9])
def test_the_mirrored_columns_hold_the_mirrored_directions(param, side, nph):
    """Column n_phi - 1 - j is column j mirrored, sub-cell column s - 1 - b is b, to rounding, and
    their weights agree; cell_sums puts every value in its mirror's cell, with that cell's weights."""
    nt = 5
    grid = SliceGrid(param, nt, nph, side)
    l = light_direction(55.0)
    geo = cells.cell_geometry(grid, l, S)
    h = cells.mirror_half(grid, l, S)
    n_eval, n_mirror = (nph + 1) // 2, nph // 2
    assert h.n_eval == n_eval and not h.v.flags.writeable
    v = geo.v.reshape(nt, nph, S, S, 3)
    np.testing.assert_array_equal(h.v.reshape(nt, n_eval, S, S, 3), v[:, :n_eval])
    for j in range(n_mirror):
        for b in range(S):
            mirror = v[:, nph - 1 - j, :, S - 1 - b] * np.array([1.0, -1.0, 1.0])
            np.testing.assert_allclose(mirror, v[:, j, :, b], rtol=0, atol=1e-14)   # a few ulps of a unit vector
            np.testing.assert_allclose(geo.w[:, nph - 1 - j, :, S - 1 - b], geo.w[:, j, :, b], rtol=1e-13, atol=1e-300)
    # values that name their sub-cell (column j, sub-cell column b) land in the mirrored cell, each
    # beside its mirror's own weight
    j = np.arange(n_eval, dtype=float)[None, :, None, None, None]
    b = np.arange(S, dtype=float)[None, None, None, :, None]
    tag = np.broadcast_to(1.0 + j + 100.0 * b, (nt, n_eval, S, S, 1)).reshape(-1, 1)
    sums = cells.cell_sums(tag, geo, h)[0]
    cols = np.arange(nph)
    src = np.minimum(cols, nph - 1 - cols)[None, :, None, None]
    sub = np.where(cols < n_eval, 1, -1)[None, :, None, None] * np.arange(S)[None, None, None, :] \
        + np.where(cols < n_eval, 0, S - 1)[None, :, None, None]
    want = ((1.0 + src + 100.0 * sub) * geo.w).sum(axis=(2, 3))
    np.testing.assert_allclose(sums, want, rtol=1e-13, atol=1e-300)
