"""Spectral values (goniometer.spectral.spectrum): interpolation, dispersion formulas against
hand-computed and catalogue values, and every bad TOML input named in its error."""

from __future__ import annotations

import numpy as np
import pytest

from goniometer.spectral import (
    Cauchy,
    Sellmeier,
    Spectral,
    Spectrum,
    SpectrumError,
    Upsampled,
    from_toml,
    is_spectral,
)

# Schott N-BK7 Sellmeier coefficients (Schott optical glass datasheet)
BK7 = {"b": [1.03961212, 0.231792344, 1.01046945], "c_um2": [0.00600069867, 0.0200179144, 103.560653]}


def test_interpolation_exact_at_nodes_and_linear_between():
    s = Spectrum((400.0, 500.0, 700.0), (1.0, 3.0, 2.0))
    np.testing.assert_array_equal(s.at(np.array([400.0, 500.0, 700.0])), [1.0, 3.0, 2.0])
    # hand: 450 is halfway 1 -> 3; 650 is 3/4 of the way 3 -> 2
    np.testing.assert_allclose(s.at([450.0, 650.0]), [2.0, 2.25], rtol=0, atol=1e-15)
    out = s.at(425.0)
    assert out.dtype == np.float64 and out.shape == () and float(out) == 1.5
    assert s.at(np.full((2, 3), 500.0)).shape == (2, 3)


def test_out_of_range_at_names_the_range():
    s = Spectrum((400.0, 700.0), (1.0, 2.0), source="test table")
    with pytest.raises(SpectrumError, match=r"test table.*399.*\[400, 700\] nm"):
        s.at([399.0, 500.0])
    with pytest.raises(SpectrumError, match=r"\[400, 700\]"):
        s.at(700.5)
    assert s.covers(400.0, 700.0) and s.covers(450.0, 650.0)
    assert not s.covers(360.0, 700.0) and not s.covers(400.0, 830.0)


def test_bin_edges_computed_in_floating_point_are_inside():
    s = Spectrum((360.0, 830.0), (0.0, 1.0))
    edges = np.linspace(360.0, 830.0, 31)
    np.testing.assert_allclose(s.at(edges), (edges - 360.0) / 470.0, atol=1e-15)


@pytest.mark.parametrize("wl, val, match", [
    ((400.0,), (1.0,), "at least 2"),
    ((400.0, 500.0), (1.0,), r"same length \(got 2 and 1\)"),
    ((500.0, 400.0), (1.0, 2.0), "strictly increasing and positive"),
    ((400.0, 400.0), (1.0, 2.0), "strictly increasing"),
    ((-1.0, 400.0), (1.0, 2.0), "positive"),
    ((400.0, float("inf")), (1.0, 2.0), "strictly increasing"),
    ((400.0, 500.0), (1.0, float("nan")), "finite"),
])
def test_spectrum_validates(wl, val, match):
    with pytest.raises(SpectrumError, match=match):
        Spectrum(wl, val)


def test_to_dict_round_trips_through_from_toml():
    s = Spectrum((400.0, 500.0), (1.5, 1.6), source="made up")
    assert s.to_dict() == {"wavelength_nm": [400.0, 500.0], "value": [1.5, 1.6], "source": "made up"}
    assert from_toml(s.to_dict(), "x") == s
    assert "source" not in Spectrum((400.0, 500.0), (1.0, 1.0)).to_dict()
    for v in (Cauchy(1.5, 0.004, 1e-4), Sellmeier(tuple(BK7["b"]), tuple(BK7["c_um2"]))):
        assert from_toml(v.to_dict(), "x") == v


def test_cauchy_against_hand_values():
    # hand: lambda = 0.5 um -> 1/lambda^2 = 4, 1/lambda^4 = 16
    n = Cauchy(1.5, 0.004, 1e-4).at(500.0)
    assert abs(float(n) - (1.5 + 0.016 + 0.0016)) < 1e-14
    assert float(Cauchy(1.5).at(633.0)) == 1.5
    assert Cauchy(1.5).covers(1.0, 1e5)
    assert from_toml({"cauchy": [1.5, 0.004]}, "x") == Cauchy(1.5, 0.004, 0.0)
    with pytest.raises(SpectrumError, match="positive"):
        Cauchy(-1.0)


def test_sellmeier_bk7_against_schott():
    bk7 = from_toml({"sellmeier": BK7}, "glass")
    # Schott N-BK7 catalogue: n_d (587.56 nm) = 1.51680, n_F (486.13) = 1.52238, n_C (656.27) = 1.51432
    np.testing.assert_allclose(bk7.at([587.56, 486.13, 656.27]), [1.51680, 1.52238, 1.51432], rtol=0, atol=1e-4)
    assert bk7.covers(360.0, 830.0)


def test_sellmeier_fused_silica_against_malitson():
    # Malitson 1965 fused silica; n(587.6 nm) = 1.4585 (refractiveindex.info / Schott lithosil)
    silica = Sellmeier((0.6961663, 0.4079426, 0.8974794), (0.0684043**2, 0.1162414**2, 9.896161**2))
    assert abs(float(silica.at(587.6)) - 1.4585) < 1e-4


def test_sellmeier_validates():
    with pytest.raises(SpectrumError, match="same"):
        Sellmeier((1.0, 2.0), (0.01,))
    with pytest.raises(SpectrumError, match="pole"):
        Sellmeier((1.0,), (0.5**2,))  # a pole at 500 nm
    with pytest.raises(SpectrumError, match=r"n\^2 must be positive"):
        Sellmeier((-3.0,), (0.01,))  # n^2 < 0 throughout


def test_spectral_alias_and_is_spectral():
    values = [Spectrum((400.0, 500.0), (1.0, 1.0)), Cauchy(1.5), Sellmeier((1.0,), (0.01,))]
    assert all(is_spectral(v) and isinstance(v, Spectral) for v in values)
    assert not is_spectral(1.5) and not is_spectral({"cauchy": [1.5]}) and not is_spectral((1.0, 1.0, 1.0))
    assert not is_spectral(Upsampled((0.1, 0.2, 0.3)))  # an RGB value resolved spectrally, not a Spectral


WHERE = "layers[2].ior"


@pytest.mark.parametrize("value, match", [
    ({"wavelength_nm": [500, 400], "value": [1, 2]},
     r"^layers\[2\]\.ior\.wavelength_nm: must be strictly increasing and positive \(got \[500, 400\]\)$"),
    ({"wavelength_nm": [0, 400], "value": [1, 2]}, r"^layers\[2\]\.ior\.wavelength_nm: .*positive"),
    ({"wavelength_nm": [400, 500, 600, 700], "value": [1, 2, 3, 4, 5]},
     r"^layers\[2\]\.ior: a table needs wavelength_nm and value of the same length \(got 4 and 5\)$"),
    ({"wavelength_nm": [400, 500]}, r"^layers\[2\]\.ior: .*missing value"),
    ({"wavelength_nm": [400, "500"], "value": [1, 2]}, r"^layers\[2\]\.ior\.wavelength_nm: must be a list of numbers"),
    ({"wavelength_nm": [400, 500], "value": [1, True]}, r"^layers\[2\]\.ior\.value: must be a list of numbers"),
    ({"wavelength_nm": [400, 500], "value": [1, 2], "units": "nm"}, r"^layers\[2\]\.ior: unknown key 'units'"),
    ({"wavelength_nm": [400, 500], "value": [1, 2], "source": 3}, r"^layers\[2\]\.ior\.source: must be a string"),
    ({"cauchy": [1.5]}, r"^layers\[2\]\.ior\.cauchy: must be \[A, B\] or \[A, B, C\]"),
    ({"cauchy": 1.5}, r"^layers\[2\]\.ior\.cauchy: must be a list of numbers"),
    ({"cauchy": [1.5, 0.0], "value": [1]}, r"^layers\[2\]\.ior: unknown key 'value'"),
    ({"cauchy": [-2.0, 0.0]}, r"^layers\[2\]\.ior\.cauchy.*positive"),
    ({"sellmeier": {"b": [1.0]}}, r"^layers\[2\]\.ior\.sellmeier: missing 'c_um2'"),
    ({"sellmeier": {"b": [1.0], "c_um2": [0.01], "d": [1]}}, r"^layers\[2\]\.ior\.sellmeier: unknown key 'd'"),
    ({"sellmeier": {"b": [1.0], "c_um2": [0.25]}}, r"^layers\[2\]\.ior\.sellmeier.*pole"),
    ({"sellmeier": [1.0, 0.01]}, r"^layers\[2\]\.ior\.sellmeier: must be a table"),
    ({"named": "Au", "part": "eta"}, r"^layers\[2\]\.ior: unknown keys 'named', 'part'.*cauchy.*sellmeier"),
    ({}, r"^layers\[2\]\.ior: an empty table"),
    (1.5, r"^layers\[2\]\.ior: a spectral value is a table"),
    ([400, 500], r"^layers\[2\]\.ior: a spectral value is a table"),
])
def test_from_toml_errors_name_the_key(value, match):
    with pytest.raises(SpectrumError, match=match):
        from_toml(value, WHERE)


def test_errors_are_one_line():
    for value in ({"wavelength_nm": list(range(100, 0, -1)), "value": [1.0] * 100}, {"x": 1}):
        with pytest.raises(SpectrumError) as info:
            from_toml(value, WHERE)
        assert "\n" not in str(info.value) and len(str(info.value)) < 300
    assert issubclass(SpectrumError, ValueError)
