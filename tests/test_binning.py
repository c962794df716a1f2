"""The one time binning and the typed energy band (rotmod.binning), and as_energy."""

from __future__ import annotations

import astropy.units as u
import numpy as np
import pytest

from rotmod._validate import as_energy, as_energy_scalar
from rotmod.binning import EDGE_TOLERANCE, EnergyBand, TimeBinning
from rotmod.errors import ParameterError

# ----------------------------------------------------------------------------- TimeBinning


def test_same_bins_compares_the_bins_not_how_a_response_averages_them():
    assert TimeBinning(12).same_bins(TimeBinning(12, "average", 8))
    assert not TimeBinning(12).same_bins(TimeBinning(24))


def test_from_edges_accepts_degree_round_off_in_any_angle_unit():
    tb = TimeBinning(36, "average", 5)
    deg = np.degrees(tb.edges())  # what a folded file stores
    for edges in (deg, deg * u.deg, np.radians(deg) * u.rad, (deg * 60.0) * u.arcmin):
        assert TimeBinning.from_edges(edges, "average", 5) == tb
    # Edges as the folding code wrote them before (linspace): a few ulp away, accepted.
    old = np.degrees(np.linspace(0.0, 2 * np.pi, 37))
    assert TimeBinning.from_edges(old) == TimeBinning(36)


@pytest.mark.parametrize(
    ("edges", "match"),
    [
        (np.linspace(0.0, 360.0, 13) + 7.5, "must be 12 equal bins over a turn"),
        (np.linspace(0.0, 180.0, 13), "must be 12 equal bins over a turn"),
        ([0.0, 100.0, 360.0], "must be 2 equal bins over a turn"),
        (np.degrees(TimeBinning(4).edges() + np.array([0, 10 * EDGE_TOLERANCE, 0, 0, 0])),
         "must be 4 equal bins"),
        ([0.0], "at least 2 edges"),
        ([[0.0, 360.0]], "bin_edges must be 1-dimensional"),
    ],
)
def test_from_edges_refuses_what_is_not_equal_bins_over_a_turn(edges, match):
    with pytest.raises(ParameterError, match=match):
        TimeBinning.from_edges(edges)


# ----------------------------------------------------------------------------- EnergyBand


def test_energy_band_values_units_and_round_trip():
    band = EnergyBand(100.0, 0.145 * u.MeV)
    assert (band.e_min, band.e_max) == (100.0, pytest.approx(145.0))
    assert repr(band) == "EnergyBand(100-145 keV)"
    assert EnergyBand.from_dict(band.to_dict()) == band
    assert EnergyBand.coerce(band) is band
    assert EnergyBand.coerce((100, 145)) == EnergyBand(100.0, 145.0)
    assert EnergyBand.coerce([100, 145] * u.keV) == EnergyBand(100.0, 145.0)
    # A closed band: zero width is the band of a single line.
    assert EnergyBand(122.0, 122.0).contains([121.9, 122.0, 122.1]).tolist() == [
        False, True, False]


def test_energy_band_contains_keeps_a_float32_line_at_an_edge():
    e32 = np.float32([99.0, 100.0, 122.1, 145.0, 146.0]).astype(float)
    assert EnergyBand(100.0, 145.0).contains(e32).tolist() == [False, True, True, True, False]
    # 122.1 is not exact in float32: its float32 value is kept by a band ending at 122.1.
    assert EnergyBand(0.0, 122.1).contains(np.float32([122.1]).astype(float)).all()
    assert EnergyBand(1.0, 2.0).contains([1500.0] * u.eV).tolist() == [True]


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((140.0, 100.0), r"energy_band must be \(lo, hi\) keV with lo <= hi, got \(140, 100\)"),
        ((-1.0, 100.0), "energy_band.e_min must be >= 0 keV, got -1 keV"),
        ((1.0, np.inf), "energy_band.e_max must be finite"),
        ((1.0 * u.cm, 2.0), "energy_band.e_min must be in units of keV"),
    ],
)
def test_energy_band_refusals_name_the_parameter(args, match):
    with pytest.raises(ParameterError, match=match):
        EnergyBand(*args)


def test_energy_band_coerce_refuses_other_shapes():
    with pytest.raises(ParameterError, match=r"energy_band must be \(lo, hi\) keV or an "
                                             "EnergyBand, got 3 values"):
        EnergyBand.coerce((1.0, 2.0, 3.0))
    with pytest.raises(ParameterError, match="energy_band must be numeric"):
        EnergyBand.coerce("soft")


# ----------------------------------------------------------------------------- as_energy


def test_as_energy_units_and_default_bound():
    assert as_energy_scalar(0.662 * u.MeV, "energy") == pytest.approx(662.0)
    assert as_energy([1.0, 2.0], "energy").tolist() == [1.0, 2.0]
    assert as_energy_scalar(0.0, "e_min", lo=0.0, lo_open=False) == 0.0
    assert as_energy([-1.0], "pulse", lo=None).tolist() == [-1.0]
    for bad, match in ((0.0, "energy must be > 0 keV, got 0 keV"),
                       (np.nan, "energy must be finite"),
                       (3.0 * u.s, "energy must be in units of keV, got s"),
                       ([1.0, 2.0], "energy must be a scalar")):
        with pytest.raises(ParameterError, match=match):
            as_energy_scalar(bad, "energy")
