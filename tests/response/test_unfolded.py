"""The unfolded response: a folded response read per time bin, with a light curve."""

import numpy as np
import pytest

from rotmod.binning import TimeBinning
from rotmod.errors import ParameterError
from rotmod.response import UnfoldedResponse, aligned_edges, build_response
from rotmod.response.columns import columns_at
from rotmod.sky.points import DirectionList
from rotmod.testing import dot_test, tiny_grid, tiny_instrument


@pytest.fixture(scope="module")
def parts():
    inst = tiny_instrument()
    grid = tiny_grid()
    return [build_response(inst, grid, TimeBinning(8), model="exact", energy=662.0,
                           dtype=np.float64) for _ in range(2)]


def _unfolded(parts, n=20, seed=1):
    rng = np.random.default_rng(seed)
    segment = (np.arange(n) >= n // 2).astype(int)
    phase = np.arange(n) % parts[0].n_time
    return UnfoldedResponse(parts, segment, phase, rng.random(n))


def test_dot_and_block_agree_with_forward(parts):
    op = _unfolded(parts)
    assert dot_test(op, rng=0) < 1e-13
    full = op.block()
    sky = np.random.default_rng(2).random(op.n_sky)
    np.testing.assert_allclose(np.einsum("dtn,n->dt", full, sky), op.forward(sky),
                               rtol=1e-13)
    np.testing.assert_array_equal(op.block(t=(3, 9), n=(1, 4)), full[:, 3:9, 1:4])


def test_bins_are_the_folded_bins_times_the_light_curve(parts):
    op = _unfolded(parts)
    folded = parts[0].materialise().matrix
    k = 4  # in segment 0, mask-angle bin 4
    np.testing.assert_allclose(op.block()[:, k, :], op.weight[k] * folded[:, 4, :],
                               rtol=1e-15)


def test_columns_at_pixel_directions_are_the_block(parts):
    op = _unfolded(parts)
    th, ph = op.grid.directions()
    cols = columns_at(op, (np.degrees(th[:3]), np.degrees(ph[:3])))
    np.testing.assert_allclose(cols, op.block(n=(0, 3)), rtol=1e-12, atol=1e-15)


def test_whole_turns_of_a_constant_source_fold_back(parts):
    # Unfolded bins over whole rotations, summed by mask-angle bin, are the folded response
    # times the number of turns: folding is the special case of a constant light curve.
    n_turns = 3
    phase = np.tile(np.arange(8), n_turns)
    op = UnfoldedResponse(parts[:1], np.zeros(phase.size, int), phase)
    sky = np.random.default_rng(3).random(op.n_sky)
    summed = op.forward(sky).reshape(op.n_det, n_turns, 8).sum(axis=1)
    np.testing.assert_allclose(summed, n_turns * parts[0].forward(sky), rtol=1e-13)


def test_aligned_edges_sit_on_the_mask_angle_boundaries():
    tb = TimeBinning(16)
    edges = aligned_edges(1.03, 7.9, tb, 4.0, start_phase=30.0)
    assert edges[0] <= 1.03 and edges[-1] >= 7.9
    np.testing.assert_allclose(np.diff(edges), 0.25, rtol=1e-12)
    xi = 2 * np.pi * edges / 4.0 + np.radians(30.0)
    frac = np.mod(xi / tb.width + 0.5, 1.0) - 0.5
    np.testing.assert_allclose(frac, 0.0, atol=1e-9)


def test_bad_input(parts):
    with pytest.raises(ParameterError, match="phase"):
        UnfoldedResponse(parts, [0, 1], [0, 8])
    with pytest.raises(ParameterError, match="weight"):
        UnfoldedResponse(parts, [0, 1], [0, 1], [1.0, -1.0])
    with pytest.raises(ParameterError, match="t_stop"):
        aligned_edges(2.0, 1.0, 8, 4.0)
    with pytest.raises(ParameterError, match="shape of parts"):
        other = build_response(tiny_instrument(), DirectionList([1.0], [2.0]), 8,
                               model="exact", energy=662.0)
        UnfoldedResponse([parts[0], other], [0, 1], [0, 1])
