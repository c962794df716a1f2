"""Response columns at chosen positions: the same numbers as the response's own pixels."""

from __future__ import annotations

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import SkyCoord

from rotmod.errors import ParameterError
from rotmod.response import build_response
from rotmod.response.columns import columns_at
from rotmod.response.drift import drift_response
from rotmod.sky import (
    Attitude,
    CelestialGrid,
    DirectionList,
    HealpixGrid,
    PositionList,
    SkyGrid,
    grid_from_dict,
)
from rotmod.testing import tiny_instrument


@pytest.fixture(scope="module")
def inst():
    return tiny_instrument()


def test_instrument_frame_columns_are_the_pixels_columns(inst):
    grid = SkyGrid.square(6, 1.5)
    resp = build_response(inst, grid, 24, energy=300, dtype=np.float64)
    th, ph = grid.directions()
    pick = [0, 5, 10, 15]
    cols = columns_at(resp, (th[pick].to(u.deg), ph[pick].to_value(u.deg)))
    np.testing.assert_allclose(cols, resp.matrix[:, :, pick], rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("kind", ["celestial", "healpix"])
def test_sky_columns_are_the_pixels_columns(inst, kind):
    att = Attitude(83.6, 22.0, roll=30.0)
    grid = (CelestialGrid((5, 5), 1.5, 84.0, 23.0, att) if kind == "celestial"
            else HealpixGrid(32, 84.0, 23.0, 4.0, att))
    resp = build_response(inst, grid, 24, energy=300, dtype=np.float64)
    sky = grid.sky_coords()
    pick = [0, 3, grid.size - 1]
    np.testing.assert_allclose(columns_at(resp, sky[pick]), resp.matrix[:, :, pick],
                               rtol=1e-9, atol=1e-14)


def test_drift_columns_sum_the_intervals_with_their_weights(inst):
    grid = CelestialGrid((4, 4), 2.0, 10.0, 5.0, Attitude(10.0, 5.0))
    intervals = [(0.0, 37.0, Attitude(10.0, 5.0, roll=0.0)),
                 (37.0, 90.0, Attitude(10.5, 5.2, roll=20.0))]
    held = drift_response(inst, grid, 24, intervals, energy=300)  # the summed matrix
    parts = drift_response(inst, grid, 24, intervals, energy=300, operator="radon",
                           tolerance=1e-3)
    assert len(parts.components()) == 2  # one (weights, spec) per interval
    pick = [1, 10]
    # Columns evaluated per interval (exact model) and weighted bin by bin = the summed
    # matrix's pixels; 1e-12: both are the exact model, the Radon table is not used.
    np.testing.assert_allclose(columns_at(parts, grid.sky_coords()[pick]),
                               held.matrix[:, :, pick], rtol=1e-9, atol=1e-12)


def test_point_lists_round_trip_and_refuse_bad_positions():
    d = DirectionList([1.0, 2.0], [30.0, 60.0])
    assert grid_from_dict(d.to_dict()) == d and d.shape == (1, 2)
    p = PositionList([10.0], [5.0], Attitude(10.0, 5.0))
    assert grid_from_dict(p.to_dict()) == p
    with pytest.raises(ParameterError, match="below the instrument's horizon"):
        PositionList([190.0], [-5.0], Attitude(10.0, 5.0))
    with pytest.raises(ParameterError, match="theta"):
        DirectionList([np.nan], [0.0])
    with pytest.raises(ParameterError, match="equal length"):
        DirectionList([1.0, 2.0], [0.0])


def test_positions_of_the_wrong_frame_are_refused(inst):
    resp = build_response(inst, SkyGrid.square(4, 1.0), 12, energy=300)
    with pytest.raises(ParameterError, match="instrument directions"):
        columns_at(resp, SkyCoord(1 * u.deg, 2 * u.deg))
    sky = build_response(inst, CelestialGrid((3, 3), 1.0, 0.0, 0.0, Attitude(0.0, 0.0)), 12,
                         energy=300)
    with pytest.raises(ParameterError, match="SkyCoord"):
        columns_at(sky, ([1.0], [2.0]))


def test_a_drift_matrix_remembers_its_intervals_also_when_stored(inst, tmp_path):
    grid = CelestialGrid((4, 4), 2.0, 10.0, 5.0, Attitude(10.0, 5.0))
    intervals = [(0.0, 37.0, Attitude(10.0, 5.0, roll=0.0)),
                 (37.0, 90.0, Attitude(10.5, 5.2, roll=20.0))]
    held = drift_response(inst, grid, 24, intervals, energy=300, dtype=np.float64)
    pick = [2, 13]
    sky = grid.sky_coords()[pick]
    # At the pixels, the columns are the summed matrix's (not the nominal attitude's).
    np.testing.assert_allclose(columns_at(held, sky), held.matrix[:, :, pick], rtol=1e-9,
                               atol=1e-12)
    from rotmod.response import open_response, save_response
    save_response(tmp_path / "drift.zarr", held)
    stored = open_response(tmp_path / "drift.zarr")  # read back from its metadata
    assert len(stored.components()) == 2
    np.testing.assert_allclose(columns_at(stored, sky), held.matrix[:, :, pick], rtol=1e-9,
                               atol=1e-12)
    np.testing.assert_allclose(columns_at(stored.materialise(), sky),
                               held.matrix[:, :, pick], rtol=1e-9, atol=1e-12)
