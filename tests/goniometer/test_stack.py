"""Material files: the TOML contract, validation messages, canonical JSON, packing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from goniometer.stack import Interface, Lambertian, Medium, Stack, StackError, load_toml, stack_from_dict
from goniometer.kernel.packing import BASE_CONDUCTOR, BASE_LAMBERTIAN, BASE_TRANSMIT, pack

EXAMPLES = Path(__file__).resolve().parents[2] / "configs" / "examples"


@pytest.mark.parametrize("name, base", [("plastic", "lambertian"), ("metal", "conductor"), ("slab", "transmit")])
def test_examples_load(name, base):
    stack, sim = load_toml(EXAMPLES / f"{name}.toml")
    assert stack.base == base
    assert stack.category == name
    assert sim["rays"] > 0
    assert stack.transmits == (base == "transmit")


def test_canonical_json_round_trip(metal, plastic, slab):
    for st in (metal, plastic, slab):
        again = Stack.from_json(st.to_json())
        assert again == st
        assert again.to_json() == st.to_json()
        assert " " not in st.to_json()


def test_toml_round_trip(tmp_path, metal, plastic):
    for st in (metal, plastic):
        p = tmp_path / "m.toml"
        p.write_text(st.to_toml())
        assert load_toml(p)[0] == st


def test_scalars_expand_to_rgb():
    st = stack_from_dict({"name": "x", "layers": [
        {"type": "interface", "roughness": 0.1, "ior": 1.5},
        {"type": "medium", "optical_depth": 0.3},
        {"type": "lambertian", "albedo": 0.5}]})
    assert st.layers[1].optical_depth == (0.3, 0.3, 0.3)
    assert st.layers[2].albedo == (0.5, 0.5, 0.5)
    assert st.layers[0].ior == (1.5, 1.5, 1.5)


def test_pack_regions():
    st = Stack("s", (Interface(0.1, (1.5,) * 3), Medium((0.1, 0.2, 0.3)), Interface(0.2, (1.3,) * 3),
                     Interface(0.3, (1.0,) * 3)))
    p = pack(st)
    assert p.base_kind == BASE_TRANSMIT
    np.testing.assert_array_equal(p.region_eta, [1.0, 1.5, 1.3, 1.0])
    np.testing.assert_array_equal(p.region_tau[1], [0.1, 0.2, 0.3])
    assert not p.region_tau[[0, 2, 3]].any()
    m = pack(Stack("m", (Interface(0.1, (1.5,) * 3), Medium((0.2,) * 3), Interface(0.2, (1.2, 1.3, 1.45), (1.0, 0.5, 0.01)))))
    assert m.base_kind == BASE_CONDUCTOR
    np.testing.assert_allclose(m.cond, [1.2 / 1.5, 1.3 / 1.5, 1.45 / 1.5, 1 / 1.5, 0.5 / 1.5, 0.01 / 1.5])
    lam = pack(Stack("l", (Lambertian((0.3, 0.4, 0.5)),)))
    assert lam.base_kind == BASE_LAMBERTIAN and lam.region_eta.shape == (1,)


BAD = [
    ("type = ", "invalid TOML"),
    ('name = "x"\n[[layers]]\ntype = "glass"\n', "layers[0].type"),
    ('name = "x"\n[[layers]]\ntype = "interface"\nroughness = 0.1\nior = 1.5\ncolour = 1\n', "layers[0].colour: unknown key"),
    ('name = "x"\n[[layers]]\ntype = "interface"\nroughness = 1.5\nior = 1.5\n', "layers[0].roughness"),
    ('name = "x"\n[[layers]]\ntype = "interface"\nroughness = -0.1\nior = 1.5\n', "layers[0].roughness"),
    ('name = "x"\n[[layers]]\ntype = "interface"\nroughness = 0.1\nior = 1.5\n[[layers]]\ntype = "medium"\noptical_depth = -1\n[[layers]]\ntype = "lambertian"\nalbedo = 0.5\n', "layers[1].optical_depth"),
    ('name = "x"\n[[layers]]\ntype = "lambertian"\nalbedo = [0.2, 1.2, 0.1]\n', "layers[0].albedo"),
    ('name = "x"\n[[layers]]\ntype = "interface"\nroughness = 0.1\nior = 1.5\nextinction = 2\n[[layers]]\ntype = "lambertian"\nalbedo = 0.5\n', "layers[0].extinction: a conductor"),
    ('name = "x"\n[[layers]]\ntype = "lambertian"\nalbedo = 0.5\n[[layers]]\ntype = "lambertian"\nalbedo = 0.5\n', "layers[0].type"),
    ('name = "x"\n[[layers]]\ntype = "interface"\nroughness = 0.1\nior = 1.5\n[[layers]]\ntype = "medium"\noptical_depth = 1\n[[layers]]\ntype = "medium"\noptical_depth = 1\n[[layers]]\ntype = "lambertian"\nalbedo = 0.5\n', "layers[2].type: two media"),
    ('name = "x"\n[[layers]]\ntype = "medium"\noptical_depth = 1\n[[layers]]\ntype = "lambertian"\nalbedo = 0.5\n', "layers[0].type: a medium cannot be the top"),
    ('name = "x"\n[[layers]]\ntype = "interface"\nroughness = 0.1\nior = 1.5\n[[layers]]\ntype = "medium"\noptical_depth = 1\n', "layers[1].type: a medium must lie above"),
    ('name = "x"\n[[layers]]\ntype = "interface"\nroughness = 0.1\nior = 0\n', "layers[0].ior"),
    ('name = "x"\n[[layers]]\ntype = "interface"\nroughness = 0.1\nior = [1.4, 1.5, 1.6]\n', "layers[0].ior: a dielectric"),
    ('name = "x"\n[[layers]]\ntype = "interface"\nroughness = 0.1\nior = [1.4, 1.5]\nextinction = 1\n', "layers[0].ior: an RGB value needs 3"),
    ('name = "x"\n[[layers]]\ntype = "interface"\nroughness = "rough"\nior = 1.5\n', "layers[0].roughness"),
    ('[[layers]]\ntype = "lambertian"\nalbedo = 0.5\n', "name: required"),
    ('name = "x"\n', "layers: required"),
    ('name = "x"\ncategory = "wood"\n[[layers]]\ntype = "lambertian"\nalbedo = 0.5\n', "category"),
    ('name = "x"\n[[layers]]\ntype = "lambertian"\nalbedo = 0.5\n[simulation]\nspeed = 3\n', "simulation.speed: unknown key"),
]


@pytest.mark.parametrize("text, expected", BAD)
def test_bad_material_files_name_file_layer_and_field(tmp_path, text, expected):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(StackError) as e:
        load_toml(p)
    msg = str(e.value)
    assert str(p) in msg and expected in msg
    assert "\n" not in msg


def test_missing_file(tmp_path):
    with pytest.raises(StackError, match="cannot read"):
        load_toml(tmp_path / "nope.toml")


# ---------------------------------------------------------------------- thin films

from goniometer.stack import Film  # noqa: E402
from goniometer.kernel.packing import FL_DL0, FL_KB0, FL_N0, FL_NA, FL_NB0, FL_ON  # noqa: E402

_WL = (450.0, 550.0, 650.0)


def _film_dict(**film):
    return {"name": "f", "layers": [{"type": "interface", "roughness": 0.1, "ior": 1.5, "film": film},
                                    {"type": "lambertian", "albedo": 0.5}]}


def test_film_parses_and_keeps_identity():
    st = stack_from_dict(_film_dict(thickness_nm=350, ior=1.33, extinction=[0.0, 0.01, 0.02]))
    f = st.layers[0].film
    assert f == Film(350.0, (1.33,) * 3, (0.0, 0.01, 0.02))
    assert '"film":{"extinction":[0.0,0.01,0.02],"ior":[1.33,1.33,1.33],"thickness_nm":350.0}' in st.to_json()
    assert Stack.from_json(st.to_json()) == st
    # without a film the canonical JSON is as before the key existed
    bare = stack_from_dict({"name": "f", "layers": [{"type": "interface", "roughness": 0.1, "ior": 1.5}]})
    assert "film" not in bare.to_json()
    assert stack_from_dict(_film_dict(thickness_nm=10, ior=[1.3, 1.4, 1.5])).layers[0].film.extinction == (0.0,) * 3


def test_film_toml_round_trip(tmp_path):
    st = stack_from_dict(_film_dict(thickness_nm=120.5, ior=[1.3, 1.4, 1.5], extinction=0.1))
    p = tmp_path / "f.toml"
    p.write_text(st.to_toml())
    assert load_toml(p)[0] == st


@pytest.mark.parametrize("film, needle", [
    ({"thickness_nm": -1.0, "ior": 1.3}, "layers[0].film.thickness_nm: -1.0 is outside [0, inf)"),
    ({"thickness_nm": float("inf"), "ior": 1.3}, "layers[0].film.thickness_nm: inf is outside [0, inf)"),
    ({"thickness_nm": float("nan"), "ior": 1.3}, "layers[0].film.thickness_nm: nan is outside [0, inf)"),
    ({"ior": 1.3}, "layers[0].film.thickness_nm: required"),
    ({"thickness_nm": 100, "ior": 0.0}, "layers[0].film.ior: 0.0 must be > 0"),
    ({"thickness_nm": 100, "ior": [1.3, -1.0, 1.3]}, "layers[0].film.ior: -1.0 must be > 0"),
    ({"thickness_nm": 100, "ior": 1.3, "extinction": -0.1}, "layers[0].film.extinction: -0.1 is outside [0.0, inf)"),
    ({"thickness_nm": 100, "ior": 1.3, "colour": 1}, "layers[0].film.colour: unknown key for a film"),
    ({"thickness_nm": 100}, "layers[0].film.ior: required"),
])
def test_film_bad_input(film, needle):
    with pytest.raises(StackError) as e:
        stack_from_dict(_film_dict(**film))
    assert needle in str(e.value), str(e.value)


def test_film_only_on_interfaces_and_in_python():
    d = {"name": "f", "layers": [{"type": "lambertian", "albedo": 0.5, "film": {"thickness_nm": 1, "ior": 1.3}}]}
    with pytest.raises(StackError, match=r"layers\[0\].film: unknown key for a lambertian layer"):
        stack_from_dict(d)
    with pytest.raises(StackError, match=r"layers\[0\].film.thickness_nm: -5.0 is outside"):
        Stack("f", (Interface(0.1, (1.5,) * 3, film=Film(-5.0, (1.3,) * 3)),))
    with pytest.raises(StackError, match=r"layers\[0\].film.extinction"):
        Stack("f", (Interface(0.1, (1.5,) * 3, film=Film(5.0, (1.3,) * 3, (0.0, -1.0, 0.0))),))


def test_film_needs_a_spectral_run():
    st = Stack("f", (Interface(0.1, (1.5,) * 3, film=Film(300.0, (1.33,) * 3)), Lambertian((0.5,) * 3)))
    with pytest.raises(StackError) as e:
        pack(st)
    assert str(e.value) == ("layers[0].film: a thin film needs a spectral run (its colours come from interference "
                            "at wavelengths; give --spectral)")
    # a film of thickness 0 is absent: packed as the bare interface, also without wavelengths
    zero = Stack("f", (Interface(0.1, (1.5,) * 3, film=Film(0.0, (1.33,) * 3)), Lambertian((0.5,) * 3)))
    bare = Stack("f", (Interface(0.1, (1.5,) * 3), Lambertian((0.5,) * 3)))
    a, b = pack(zero), pack(bare)
    assert not a.has_film
    for x, y in zip(a.as_tuple(), b.as_tuple()):
        assert np.array_equal(x, y)


def test_film_packed_columns():
    st = Stack("f", (Interface(0.1, (1.5,) * 3, film=Film(300.0, (1.33, 1.34, 1.35), (0.0, 0.1, 0.2))),
                     Medium((0.1,) * 3),
                     Interface(0.2, (0.2, 0.3, 0.4), (3.0, 2.5, 2.0), film=Film(55.0, (1.46,) * 3))),
               "metal", wavelengths_nm=_WL)
    p = pack(st)
    assert p.has_film
    assert p.if_film[0, FL_ON] == 1.0 and p.if_film[1, FL_ON] == 1.0
    assert np.allclose(p.if_film[0, FL_DL0:FL_DL0 + 3], 300.0 / np.asarray(_WL))
    assert np.array_equal(p.if_film[0, FL_N0:FL_N0 + 3], (1.33, 1.34, 1.35))
    assert p.if_film[0, FL_NA] == 1.0 and p.if_film[1, FL_NA] == 1.5
    assert np.array_equal(p.if_film[0, FL_NB0:FL_NB0 + 3], (1.5,) * 3)
    assert np.array_equal(p.if_film[1, FL_NB0:FL_NB0 + 3], (0.2, 0.3, 0.4))
    assert np.array_equal(p.if_film[1, FL_KB0:FL_KB0 + 3], (3.0, 2.5, 2.0))
