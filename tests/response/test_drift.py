"""The drift response through one Radon table (RadonDriftResponse) against independent
evidence: the per-interval sum it replaces, the exact model, and the symmetries of a roll."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from rotmod import DetectorArray, Instrument
from rotmod.errors import ParameterError
from rotmod.io import load_instrument
from rotmod.response import RadonResponse, TimeBinning, build_response
from rotmod.response.drift import RadonDriftResponse, drift_response
from rotmod.response.spec import as_spec
from rotmod.sky import Attitude, AttitudeTable, CelestialGrid, HealpixGrid, SkyGrid
from rotmod.sky.attitude import attitude_rotations
from rotmod.testing import dot_test

PROTO = load_instrument("prototype")  # 19 detectors, a 60 s rotation
ATT0 = Attitude(200.0, -60.0, 10.0)
GRID = CelestialGrid((5, 5), 1.2, 200.4, -59.6, ATT0)
BINS = TimeBinning(24, "average", 2)


def _drifting(n: int = 6) -> list[tuple[float, float, Attitude]]:
    """``n`` intervals of 13-47 s (shorter and longer than a turn) while the gondola drifts
    1.5 deg in RA, 1 deg in Dec and turns 50 deg."""
    rng = np.random.default_rng(7)
    out, t = [], 0.0
    for k in range(n):
        dt = float(rng.uniform(13.0, 47.0))
        f = k / max(1, n - 1)
        out.append((t, t + dt, Attitude(200.0 + 1.5 * f, -60.0 + 1.0 * f, 10.0 + 50.0 * f)))
        t += dt
    return out


def test_rotations_are_the_attitudes_instrument_frames() -> None:
    rng = np.random.default_rng(0)
    atts = [Attitude(rng.uniform(0, 360), rng.uniform(-85, 85), rng.uniform(0, 360))
            for _ in range(4)]
    sky = GRID.sky_coords()
    s = sky.cartesian.xyz.value.T
    for att, m in zip(atts, attitude_rotations(atts), strict=True):
        theta, phi = att.to_instrument(sky)
        u = s @ m.T
        # The same rotation as astropy's SkyOffsetFrame, to float64 rounding of angles.
        np.testing.assert_allclose(np.arccos(u[:, 2]), theta.value, atol=1e-12)
        np.testing.assert_allclose(np.exp(1j * np.arctan2(u[:, 1], u[:, 0])),
                                   np.exp(1j * phi.value), atol=1e-12)


def test_one_table_matches_the_per_interval_sum_and_the_exact_model() -> None:
    tol = 1e-3  # a coarse table keeps the six per-interval operators fast to build
    steps = _drifting(6)
    shared = drift_response(PROTO, GRID, BINS, steps, energy=122, operator="radon",
                            tolerance=tol)
    assert isinstance(shared, RadonDriftResponse)
    assert len(shared.components()) == 6 and shared.n_pairs < 6 * BINS.n_bins
    parts = drift_response(PROTO, GRID, BINS, steps, energy=122,
                           operator="radon-per-interval", tolerance=tol)
    exact = drift_response(PROTO, GRID, BINS, steps, energy=122).matrix
    values = shared.materialise().matrix
    # Every drift value is an exposure-weighted mean of per-interval values, each within the
    # tolerance of the exact model (the same table step law, exact pixel geometry).
    assert np.abs(values - exact).max() <= tol
    # Against today's per-interval sum: both interpolate the same table nodes; they differ
    # only by the optical-depth nodes (one range for every interval instead of one each),
    # whose share of the error budget is a tenth of the tolerance (radon.RING_SHARE).
    assert np.abs(values - parts.materialise().matrix).max() <= 0.1 * tol
    rng = np.random.default_rng(2)
    x, y = rng.random(GRID.size), rng.random((shared.n_det, shared.n_time))
    # The products are those of the values (the materialised columns are forward products
    # of unit vectors, so this checks the adjoint and linearity).
    np.testing.assert_allclose(shared.forward(x), values @ x, rtol=1e-12)
    np.testing.assert_allclose(shared.adjoint(y), np.einsum("dtn,dt->n", values, y),
                               rtol=1e-12)


def test_a_healpix_grid_drifts_as_the_exact_model() -> None:
    tol = 1e-3
    grid = HealpixGrid(64, 200.4, -59.6, 2.0, ATT0)
    steps = _drifting(4)
    shared = drift_response(PROTO, grid, BINS, steps, energy=122, operator="radon",
                            tolerance=tol)
    exact = drift_response(PROTO, grid, BINS, steps, energy=122).matrix
    # Any grid with pixels on the sky: the same promise as on a celestial grid.
    assert np.abs(shared.materialise().matrix - exact).max() <= tol


def test_dot_test_float64_and_float32_agrees() -> None:
    steps = _drifting(5)
    r64 = drift_response(PROTO, GRID, BINS, steps, energy=122, operator="radon",
                         tolerance=1e-3)
    # Forward and adjoint use the same weights: the dot test holds to rounding.
    dot_test(r64, rng=np.random.default_rng(3), rtol=1e-12)
    r32 = drift_response(PROTO, GRID, BINS, steps, energy=122, operator="radon",
                         tolerance=1e-3, dtype=np.float32)
    rng = np.random.default_rng(4)
    x, y = rng.random(GRID.size), rng.random((r32.n_det, r32.n_time))
    assert r32.forward(x).dtype == np.float32
    # float32 rounding of sums of ~1e4 terms: ~1e-6 relative.
    np.testing.assert_allclose(r32.forward(x), r64.forward(x), rtol=1e-5)
    np.testing.assert_allclose(r32.adjoint(y), r64.adjoint(y), rtol=1e-5)


def test_a_roll_is_a_shift_of_the_mask_angle() -> None:
    # A roll by m bin widths turns the sky by m bins against the mask and the detectors by
    # m bins against the sky: the drift response of the rolled attitude is the nominal
    # attitude's response of the detectors turned back by the roll, m bins later
    # (docs/physics.md 2c).  Two whole turns: every bin has the same exposure.
    m = 3
    roll = m * 360.0 / BINS.n_bins
    rolled = Attitude(ATT0.ra, ATT0.dec, ATT0.roll + roll)
    drift = drift_response(PROTO, GRID, BINS, [(0.0, 120.0, rolled)], energy=122,
                           operator="radon")
    a = np.radians(-roll)
    pos = PROTO.detectors.positions @ np.array([[np.cos(a), np.sin(a)],
                                                [-np.sin(a), np.cos(a)]])
    turned = Instrument(PROTO.mask, DetectorArray(pos, PROTO.detectors.diameter))
    ref = RadonResponse(turned, GRID, BINS, 122, dtype=np.float64).materialise().matrix
    # The same table nodes and weights, the geometry computed two ways (a rotation matrix
    # here, astropy's frames there): equal to float64 rounding.
    np.testing.assert_allclose(drift.materialise().matrix, np.roll(ref, -m, axis=1),
                               rtol=0, atol=1e-10)


def test_one_attitude_is_the_radon_response_however_it_is_cut() -> None:
    ref = RadonResponse(PROTO, GRID, BINS, 122, dtype=np.float64)
    whole = drift_response(PROTO, GRID, BINS, [(0.0, 120.0, ATT0)], energy=122,
                           operator="radon")
    # The same attitude cut into five pieces, one shorter than a bin: one pair per bin.
    edges = [0.0, 0.7, 31.0, 60.0, 100.0, 120.0]
    cut = drift_response(PROTO, GRID, BINS,
                         [(lo, hi, ATT0) for lo, hi in itertools.pairwise(edges)],
                         energy=122, operator="radon")
    # Whole turns of one attitude: bins t and t + n/2 share their pairs (the half turn), so
    # half the bins are computed, as RadonResponse does.
    assert whole.n_pairs == cut.n_pairs == BINS.n_bins // 2
    rng = np.random.default_rng(5)
    x, y = rng.random(GRID.size), rng.random((ref.n_det, ref.n_time))
    fx, aty = ref.forward(x), ref.adjoint(y)
    # The same table and weights: equal to float64 rounding of the geometry and the sums.
    for op in (whole, cut):
        np.testing.assert_allclose(op.forward(x), fx, rtol=1e-10, atol=1e-12 * fx.max())
        np.testing.assert_allclose(op.adjoint(y), aty, rtol=1e-10, atol=1e-12 * aty.max())


def test_bad_input_is_refused_with_the_rule() -> None:
    spec = drift_response(PROTO, GRID, BINS, [(0.0, 60.0, ATT0)], energy=122,
                          operator="radon").spec
    with pytest.raises(ParameterError, match=r"weights must be .* \(1, 24\)"):
        RadonDriftResponse(spec, [ATT0], np.ones((2, 24)))
    on_axis = as_spec(PROTO, SkyGrid.square(3, 1.0), BINS, "exact", 122, dtype=np.float64)
    with pytest.raises(ParameterError, match="pixels on the sky"):
        RadonDriftResponse(on_axis, [ATT0], np.ones((1, 24)))
    away = Attitude(20.0, 60.0, 0.0)  # the field is ~120 deg from this pointing
    with pytest.raises(ParameterError, match="above the detector plane"):
        drift_response(PROTO, GRID, BINS, [(0.0, 60.0, ATT0), (60.0, 90.0, away)],
                       energy=122, operator="radon")
    with pytest.raises(ParameterError, match="'radon-per-interval'"):
        drift_response(PROTO, GRID, BINS, [(0.0, 60.0, ATT0)], energy=122, operator="radn")
    with pytest.raises(ParameterError, match="exact model"):
        drift_response(PROTO, GRID, BINS, [(0.0, 60.0, ATT0)], "advanced", 122,
                       operator="radon")


def test_the_pieces_of_an_attitude_table_end_on_its_samples_and_never_past_them() -> None:
    # The drift response's intervals come from AttitudeTable.intervals: over exactly the
    # table's span they end on its last sample; past it the table refuses, where it held
    # its last attitude (a drift silently frozen in the response).
    drifting = AttitudeTable([0.0, 60.0, 120.0], [200.0, 200.5, 201.0], [-60.0, -60.3, -60.6],
                             [10.0, 20.0, 30.0])
    assert drifting.intervals(0.0, 120.0, 40.0)[-1][1] == 120.0
    with pytest.raises(ParameterError, match=r"covers 0 \.\. 120 s, but t_start \.\. t_stop "
                                             r"= 0 \.\. 180 s ends 60 s after its last"):
        drifting.intervals(0.0, 180.0, 40.0)
    # Independent evidence that the pieces of the whole span are used whole: a table holding
    # ATT0 over two turns gives ATT0's own response (one attitude, whole turns: every bin
    # has the same exposure), to float64 rounding of the geometry.
    held = AttitudeTable([0.0, 120.0], [ATT0.ra] * 2, [ATT0.dec] * 2, [ATT0.roll] * 2)
    steps = held.intervals(0.0, 120.0, 40.0)
    drift = drift_response(PROTO, GRID, BINS, steps, energy=122)
    ref = build_response(PROTO, GRID, BINS, energy=122, dtype=np.float64).matrix
    np.testing.assert_allclose(drift.matrix, ref, rtol=0, atol=1e-10 * ref.max())
