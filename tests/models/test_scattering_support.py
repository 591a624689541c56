"""No model represents a scattering medium yet: one shared refusal, with a clear reason."""

from __future__ import annotations

import json

import pytest

from goniometer.cli import main
from goniometer.stack import Interface, Lambertian, Medium, Stack
from models import registry
from models.base import ModelError, scattering_reason
from models.belcour import pack_stack

#: Bati 2019 appendix E's medium (d = 2) over its rough conductor, under a smooth index-matched top
SCATTERING = Stack("appendix-e", (Interface(0.0, (1.0,) * 3), Medium((0.4, 0.4, 2.2), (0.5, 0.5, 1 / 1.1), 0.6),
                                  Interface(0.2, (1.5,) * 3, (3.0, 0.0, 0.0))), "metal")
#: the same medium with the albedo only where tau = 0: it does not scatter
ABSORBING = Stack("absorbing", (Interface(0.1, (1.5,) * 3), Medium((0.4, 0.4, 0.0), (0.0, 0.0, 0.9), 0.6),
                                Lambertian((0.5,) * 3)), "plastic")


@pytest.mark.parametrize("name", list(registry.all_models()))
def test_every_analytic_model_refuses_a_scattering_medium(name):
    model = registry.all_models()[name]
    assert not model.scattering
    reason = model.reason(SCATTERING)
    assert reason == scattering_reason(SCATTERING)
    assert reason.startswith("purely absorbing media only (layers[1] is a scattering medium")
    with pytest.raises(ModelError, match="scattering medium"):
        model.evaluate(SCATTERING, [0.0, 0.0, 1.0], [[0.0, 0.0, 1.0]], model.sides[0])
    # a medium that does not scatter is not refused for scattering
    assert "scattering" not in (model.reason(ABSORBING) or "")


def test_belcour_packing_refuses_it_too():
    with pytest.raises(ValueError, match="scattering medium"):
        pack_stack(SCATTERING)


def test_fitted_models_accept_any_stack_and_gonio_models_says_who_supports_scattering(capsys):
    assert all(c.scattering for c in registry.fitted_models().values())
    assert main(["models", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert {n for n, m in d.items() if m["scattering"]} == set(registry.fitted_models())
