"""models.compare.integrate: cell averages of analytic BSDFs on the reference grids."""

from __future__ import annotations

import numpy as np
import pytest

from goniometer import optics
from goniometer.run.settings import SimulationSettings
from goniometer.run.loop import simulate
from goniometer.grids.slice_grid import SliceGrid, light_direction
from goniometer.stack import Interface, Stack
from models.base import Model, ModelValue
from models.compare.integrate import integrate, integrate_slice
from goniometer.testing import assert_cells_match


class Constant(Model):
    name = "constant"
    sides = ("brdf", "btdf")

    def support_reason(self, stack):
        return None

    def _evaluate(self, stack, l, v, side):
        top = np.broadcast_to(np.array([0.1, 0.2, 0.3]), v.shape).copy()
        return ModelValue(top, 2 * top)


class SingleInterface(Model):
    """The exact Walter 2007 BSDF of a single rough interface (the simulator's oracle)."""

    name = "single-interface"
    sides = ("brdf", "btdf")

    def support_reason(self, stack):
        return None if len(stack.layers) == 1 else "single interfaces only"

    def _evaluate(self, stack, l, v, side):
        x = stack.layers[0]
        a = x.roughness
        out = np.zeros(v.shape)
        for c in range(3):
            if side == "brdf":
                out[..., c] = optics.np_microfacet_reflection(l[0], l[1], l[2], v[..., 0], v[..., 1], v[..., 2], a, a,
                                                              x.ior[c], x.extinction[c], False)
            else:
                out[..., c] = optics.np_microfacet_transmission(l[0], l[1], l[2], v[..., 0], v[..., 1], v[..., 2], a, a,
                                                                x.ior[c], False)
        return ModelValue(out, np.zeros_like(out))


@pytest.mark.parametrize("param", ["classic", "half"])
@pytest.mark.parametrize("side", ["reflection", "transmission"])
def test_constant_integrates_to_itself(param, side):
    g = SliceGrid(param, 30, 60, side)
    l = light_direction(50.0)
    top, internal = integrate_slice(Constant(), Stack("x", (Interface(0.1, (1.5,) * 3),)), g, l, s=4)
    valid = g.mask(l)
    np.testing.assert_allclose(top[:, valid], np.broadcast_to(np.array([[0.1], [0.2], [0.3]]), top[:, valid].shape), rtol=1e-13)
    np.testing.assert_allclose(internal[:, valid], np.broadcast_to(np.array([[0.2], [0.4], [0.6]]), top[:, valid].shape), rtol=1e-13)


@pytest.mark.parametrize("param", ["classic", "half"])
def test_single_interface_model_matches_simulation(param):
    st = Stack("glass", (Interface(0.15, (1.5,) * 3),))
    ref = simulate(st, SimulationSettings(incident_deg=(20.0, 65.0), rays=1_000_000, resolution=(30, 60),
                                          parametrization=param, seed=21))
    for side, sd in (("brdf", ref.brdf), ("btdf", ref.btdf)):
        ms = integrate(SingleInterface(), ref, side, s=9 if side == "brdf" else 15)
        for m in range(2):
            assert_cells_match(sd.value[m], sd.stderr[m], ms.total[m], sd.proj_solid_angle[m], ref.settings.rays)
