"""The response operator: binning, materialised and matrix-free implementations."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse.linalg import lsqr

from rotmod import DetectorArray, Instrument
from rotmod.errors import InstrumentMismatchError, ModelValidityError, ParameterError
from rotmod.materials import PAPER_SIGMA_662
from rotmod.profiles import get_model
from rotmod.response import (
    MaterialisedResponse,
    MatrixFreeResponse,
    RadonResponse,
    ResponseSpec,
    TimeBinning,
    build_response,
    save_response,
)
from rotmod.sky import SkyGrid
from rotmod.testing import MatrixOperator, dot_test
from tests.conftest import rad


@pytest.fixture(scope="module")
def grid():
    return SkyGrid((9, 8), 1.0)


@pytest.fixture(scope="module")
def mat(inst, grid):
    return build_response(inst, grid, 48, "advanced-approx", dtype=np.float64)


# ------------------------------------------------------------------------- time binning
def test_time_binning_angles():
    tb = TimeBinning(8)
    np.testing.assert_allclose(tb.edges(), np.linspace(0, 2 * np.pi, 9))
    np.testing.assert_allclose(tb.angles(), (np.arange(8) + 0.5) * np.pi / 4)
    assert tb.sub_angles().shape == (1, 8)
    av = TimeBinning(8, "average", n_sub=4)
    sub = av.sub_angles()
    assert sub.shape == (4, 8)
    # Sub-samples lie inside their bin and average to the bin centre.
    assert np.all((sub >= av.edges()[:-1]) & (sub < av.edges()[1:]))
    np.testing.assert_allclose(sub.mean(axis=0), av.angles(), rtol=1e-14)
    assert TimeBinning.from_dict(av.to_dict()) == av
    np.testing.assert_array_equal(tb.bin_of([0.0, 2 * np.pi - 1e-12, 2 * np.pi]), [0, 7, 0])


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((0,), "time_bins.n_bins"),
        ((2.5,), "time_bins.n_bins"),
        ((8, "middle"), "time_bins.mode"),
        ((8, "average", 0), "time_bins.n_sub"),
    ],
)
def test_time_binning_errors(args, match):
    with pytest.raises(ParameterError, match=match):
        TimeBinning(*args)


def test_average_of_constant_in_bin_profile():
    """A point source on the axis has a constant profile: every bin average equals it."""
    inst = Instrument.paper(sigma=PAPER_SIGMA_662)
    grid = SkyGrid((1, 1), 0.1)  # one pixel, on the axis
    c = build_response(inst, grid, 24, "advanced-approx", dtype=np.float64)
    a = build_response(inst, grid, TimeBinning(24, "average", 5), dtype=np.float64)
    # On the axis uc = s = 0 for every mask angle, so the profile is exactly constant.
    np.testing.assert_allclose(a.matrix, c.matrix, rtol=0, atol=1e-15)
    assert np.ptp(c.matrix) < 1e-15


def test_average_converges_with_n_sub(inst, grid):
    model = get_model("advanced-approx")
    theta, phi = grid.directions()
    tb = TimeBinning(24)
    # Reference bin means from a dense midpoint rule (400 samples per bin).
    dense = TimeBinning(24, "average", 400).sub_angles()
    ref = model.profile(inst, rad(theta), rad(phi), rad(dense.T.ravel())).reshape(7, 24, 400,
                                                                                  -1).mean(axis=2)
    errs = []
    for n_sub in (1, 2, 4, 8, 16):
        r = build_response(inst, grid, TimeBinning(24, "average", n_sub), dtype=np.float64)
        errs.append(np.abs(r.matrix - ref).max())
    # n_sub = 1 is the bin centre.
    c = build_response(inst, grid, tb, dtype=np.float64)
    np.testing.assert_array_equal(
        build_response(inst, grid, TimeBinning(24, "average", 1), dtype=np.float64).matrix,
        c.matrix,
    )
    # The profile has kinks (slat edges), so the midpoint rule converges at first to second
    # order; require a monotonic decrease and a >10x gain from 1 to 16 sub-samples.
    assert all(e2 < e1 for e1, e2 in itertools.pairwise(errs))
    assert errs[-1] < errs[0] / 10


# ------------------------------------------------------------------ materialised response
def test_columns_equal_model_profile(inst, grid, mat):
    theta, phi = grid.directions()
    model = get_model("advanced-approx")
    for n in (0, 17, 40, 71):
        col = model.profile(inst, rad(theta[n]), rad(phi[n]), rad(TimeBinning(48).angles()))[:, :,
                                                                                             0]
        # Same kernel on the same float64 inputs; the kernels may vectorise over the sky
        # axis (SIMD lanes vs scalar tail), which changes the last bit or two: 1e-14.
        np.testing.assert_allclose(mat.matrix[:, :, n], col, rtol=0, atol=1e-14)


def test_metadata(inst, grid, mat):
    md = mat.metadata()
    assert md["instrument"] == inst.to_dict()
    assert md["grid"] == grid.to_dict()
    assert md["time_bins"] == {"n_bins": 48, "mode": "center", "n_sub": 1}
    assert md["model"]["model"] == "advanced-approx"
    assert md["dtype"] == "float64"
    assert md["shape"] == [7, 48, 72]


def test_float32_and_detector_subset(inst, grid, mat):
    r32 = build_response(inst, grid, 48, "advanced-approx")
    assert r32.matrix.dtype == np.float32
    # float32 storage of values in [0, 1]: rounding <= 2^-24.
    np.testing.assert_allclose(r32.matrix, mat.matrix, atol=6e-8, rtol=0)
    sub = build_response(inst, grid, 48, "advanced-approx", detectors=[3, 0], dtype=np.float64)
    assert len(sub.instrument.detectors) == 2
    np.testing.assert_array_equal(sub.matrix, mat.matrix[[3, 0]])
    x = np.ones(72)
    assert r32.forward(x).dtype == np.float32
    assert r32.adjoint(np.ones((7, 48))).dtype == np.float32


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_dot_test_materialised(mat, seed):
    # float64 sums of ~24000 positive terms: relative rounding ~1e-15; allow 1e-12.
    dot_test(mat, rng=np.random.default_rng(seed), rtol=1e-12)


def test_dot_test_float32(inst, grid):
    r = build_response(inst, grid, 48, "advanced-approx")
    # float32 BLAS sums of up to 336 terms: relative error ~ 336 * 6e-8 worst case.
    dot_test(r, rng=np.random.default_rng(1), rtol=3e-5)


def test_sensitivity(mat):
    np.testing.assert_allclose(mat.sensitivity(), mat.matrix.sum(axis=(0, 1)), rtol=1e-12)


def test_bad_products(mat):
    with pytest.raises(ParameterError, match="sky must have shape"):
        mat.forward(np.ones(5))
    with pytest.raises(ParameterError, match="counts must have shape"):
        mat.adjoint(np.ones((7, 3)))


@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        ({"model": "nope"}, ParameterError, "model must be one of"),
        ({"dtype": np.int32}, ParameterError, "dtype must be float32 or float64"),
        ({"detectors": [9]}, ParameterError, "detectors must be indices"),
        ({"time_bins": "x"}, ParameterError, "time_bins must be"),
        ({"grid": "x"}, ParameterError, "grid must be a sky grid"),
        ({"instrument": None}, ParameterError, "instrument must be an Instrument"),
        ({"energy": -5.0}, ParameterError, "energy must be > 0"),
    ],
)
def test_build_errors(inst, grid, kwargs, exc, match):
    args = {"instrument": inst, "grid": grid, "time_bins": 8} | kwargs
    with pytest.raises(exc, match=match):
        build_response(**args)


def test_model_validity_refused():
    # Thick slats: h tan(theta) > a at the field edge; the advanced model refuses.
    inst = Instrument.paper(h=60.0, sigma=PAPER_SIGMA_662)
    with pytest.raises(ModelValidityError, match="advanced model needs"):
        build_response(inst, SkyGrid((4, 4), 2.0), 8, "advanced")


def test_materialised_errors():
    with pytest.raises(ParameterError, match="matrix must have shape"):
        MaterialisedResponse(np.ones((3, 4)))
    with pytest.raises(ParameterError, match="matrix must be float32 or float64"):
        MaterialisedResponse(np.ones((1, 3, 4), dtype=np.int64))
    with pytest.raises(ParameterError, match="grid has 16 pixels"):
        MaterialisedResponse(np.ones((1, 3, 4)), grid=SkyGrid((4, 4), 1.0))


# --------------------------------------------------------------------- matrix-free response
@pytest.fixture(scope="module")
def mfree(inst, grid):
    # Small blocks so that several time and sky blocks (with ragged ends) are exercised.
    return MatrixFreeResponse(inst, grid, 48, "advanced-approx", block_size=(10, 30))


def test_matrix_free_equals_materialised(mat, mfree):
    rng = np.random.default_rng(3)
    x = rng.random(72)
    y = rng.random((7, 48))
    # Same kernel values; only the summation order differs (blocks): float64 rounding.
    np.testing.assert_allclose(mfree.forward(x), mat.forward(x), rtol=1e-12)
    np.testing.assert_allclose(mfree.adjoint(y), mat.adjoint(y), rtol=1e-12)
    f, a = mfree.forward_adjoint(x, y)
    np.testing.assert_array_equal(f, mfree.forward(x))
    np.testing.assert_array_equal(a, mfree.adjoint(y))
    np.testing.assert_allclose(mfree.materialise().matrix, mat.matrix, rtol=0, atol=1e-14)
    np.testing.assert_allclose(mfree.sensitivity(), mat.sensitivity(), rtol=1e-12)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_dot_test_matrix_free(mfree, seed):
    dot_test(mfree, rng=np.random.default_rng(seed), rtol=1e-12)


def test_matrix_free_average_mode(inst, grid):
    tb = TimeBinning(12, "average", 3)
    m = MatrixFreeResponse(inst, grid, tb, block_size=(5, 50))
    ref = build_response(inst, grid, tb, dtype=np.float64)
    # Different block shapes: last-bit differences from SIMD vectorisation only.
    np.testing.assert_allclose(m.materialise().matrix, ref.matrix, rtol=0, atol=1e-14)


@pytest.mark.parametrize("op_name", ["mat", "mfree"])
def test_lsqr_recovers_sky(request, op_name):
    op = request.getfixturevalue(op_name)
    sky = np.zeros(op.n_sky)
    sky[[5, 30, 61]] = [1.0, 2.0, 0.5]
    data = op.forward(sky).ravel()
    lin = op.as_linear_operator()
    sol = lsqr(lin, data, atol=1e-12, btol=1e-12, iter_lim=2000)[0]
    # Noise-free data and a well-posed small problem (504 equations, 72 unknowns): the
    # least-squares solution is the sky itself up to the solver's tolerance.
    np.testing.assert_allclose(sol, sky, atol=1e-4)


def test_half_turn_symmetry(inst, grid):
    # Even N: only bins 0..N/2-1 are computed and repeated; the result must equal the model
    # at every bin centre (the mask maps onto itself under a half turn).  Odd N: no pair of
    # bins is half a turn apart, all are computed.  The whole-turn comparison in
    # test_columns_equal_model_profile covers the same for 48 bins.
    from rotmod.response import ResponseSpec
    from rotmod.response._plan import make_plan

    theta, phi = grid.directions()
    for n_bins, distinct in ((20, 10), (15, 15)):
        plan = make_plan(ResponseSpec(inst, grid, n_bins, "exact", dtype=np.float64))
        assert plan.n_distinct == distinct
        ref = get_model("exact").profile(inst, rad(theta), rad(phi),
                                         rad(TimeBinning(n_bins).angles()))
        for op in (
            build_response(inst, grid, n_bins, "exact", dtype=np.float64),
            MatrixFreeResponse(inst, grid, n_bins, "exact", block_size=(3, 40)).materialise(),
        ):
            np.testing.assert_allclose(op.matrix, ref, rtol=0, atol=1e-14)

    class Asymmetric(type(get_model("exact"))):
        half_turn_symmetric = False

    assert make_plan(ResponseSpec(inst, grid, 20, Asymmetric())).n_distinct == 20


def test_other_models_build(inst, grid):
    theta, phi = grid.directions()
    xi = TimeBinning(16).angles()
    for name in ("advanced-g0", "exact"):
        r = build_response(inst, grid, 16, name, dtype=np.float64)
        p = get_model(name).profile(inst, rad(theta), rad(phi), rad(xi))
        np.testing.assert_allclose(r.matrix, p, rtol=0, atol=1e-14)  # same kernel call


def test_block_size_errors(inst, grid):
    with pytest.raises(ParameterError, match="block_size"):
        MatrixFreeResponse(inst, grid, 8, block_size=(0, 4))


# ------------------------------------------------------------------------ response spec
def test_spec_validates_once_and_round_trips(inst, grid):
    from rotmod.response import ResponseSpec

    spec = ResponseSpec(inst, grid, 12, "advanced-approx", 662.0, dtype="float64",
                        detectors=[2, 0])
    assert spec.shape == (2, 12, grid.size) and spec.time_bins == TimeBinning(12)
    assert spec.model.describe() == get_model("advanced-approx").describe()
    assert spec.dtype == np.float64 and spec.energy == 662.0 and spec.distance is None
    back = ResponseSpec.from_dict(spec.to_dict())
    assert back == spec and back.to_dict() == spec.to_dict()
    assert spec.replace(energy=511.0) != spec
    back.matches(spec)  # the same response: no error
    spec.matches(spec.to_dict())
    with pytest.raises(InstrumentMismatchError, match=r"time_bins\.n_bins is 12 in the store "
                                                      r"but 14 here"):
        spec.replace(time_bins=14).matches(spec)
    with pytest.raises(InstrumentMismatchError, match=r"energy is 662\.0 in the store but 511\.0"):
        spec.replace(energy=511.0).matches(spec)
    # The messages every operator gave before the spec existed.
    for kwargs, message in (
        ({"instrument": "paper"}, "instrument must be an Instrument, got str"),
        ({"grid": 3}, "grid must be a sky grid"),
        ({"time_bins": 0}, "time_bins"),
        ({"dtype": "int32"}, "dtype must be float32 or float64"),
        ({"detectors": [7]}, r"detectors must be indices in \[0, 6\]"),
        ({"energy": -1.0}, "energy"),
        ({"model": "nope"}, "model"),
    ):
        args = {"instrument": inst, "grid": grid, "time_bins": 12, **kwargs}
        with pytest.raises(ParameterError, match=message):
            ResponseSpec(**args)


def test_every_builder_takes_one_spec(inst, grid):
    from rotmod.response import RadonResponse, ResponseSpec

    spec = ResponseSpec(inst, grid, 12, "advanced-approx", dtype=np.float64)
    ref = build_response(inst, grid, 12, "advanced-approx", dtype=np.float64)
    by_spec = build_response(spec)
    assert by_spec.spec is spec and by_spec.metadata() == ref.metadata()
    np.testing.assert_array_equal(by_spec.matrix, ref.matrix)
    free = MatrixFreeResponse(spec, block_size=(5, 30))
    assert free.spec is spec
    np.testing.assert_array_equal(free.materialise().matrix, ref.matrix)
    with pytest.raises(ParameterError, match=r"either a ResponseSpec or its fields.*dtype"):
        build_response(spec, dtype=np.float32)
    with pytest.raises(ParameterError, match="exact model"):
        RadonResponse(spec)


def test_block_and_materialise_are_the_same_values_for_every_operator(inst, grid, mat):
    free = MatrixFreeResponse(inst, grid, 48, "advanced-approx", block_size=(7, 20))
    # (As test_matrix_free_equals_materialised: other kernel-call shapes, 1e-14.)
    # MatrixOperator has only forward and adjoint: block and materialise are the defaults.
    for op in (mat, free, MatrixOperator(mat.matrix)):
        np.testing.assert_allclose(op.block(t=(3, 40), n=(5, 61)), mat.matrix[:, 3:40, 5:61],
                                   rtol=0, atol=1e-14)
        np.testing.assert_allclose(op.materialise().matrix, mat.matrix, rtol=0, atol=1e-14)
    assert mat.materialise() is mat


# ------------------------------------------------------------------ block ranges, checked
@pytest.mark.parametrize(
    ("t", "n", "match"),
    [
        (None, (-1, 2), r"n must satisfy 0 <= n0 < n1 <= n_sky = 72, got \(-1, 2\)"),
        ((0, 49), None, r"t must satisfy 0 <= t0 < t1 <= n_time = 48, got \(0, 49\)"),
        ((2, 1), None, r"t must satisfy 0 <= t0 < t1 <= n_time = 48, got \(2, 1\)"),
        ((3, 3), None, r"t must satisfy .*got \(3, 3\)"),
        (None, (70, 73), r"n must satisfy 0 <= n0 < n1 <= n_sky = 72, got \(70, 73\)"),
        ((0.0, 2), None, r"t must be a pair of integers \(t0, t1\) with 0 <= t0 < t1 <= "
                         r"n_time = 48, got \(0\.0, 2\)"),
        ((False, 2), None, r"t must be a pair of integers"),
        (5, None, r"t must be a pair of integers .*got 5"),
        (None, (0, 1, 2), r"n must be a pair of integers \(n0, n1\) .*got \(0, 1, 2\)"),
    ],
)
def test_every_operator_checks_its_block_ranges(inst, grid, mat, tmp_path, t, n, match):
    ops = {
        "materialised": mat,
        "matrix-free": MatrixFreeResponse(inst, grid, 48, "advanced-approx", block_size=(7, 20)),
        "stored": save_response(tmp_path / "r.zarr", mat, chunks=(10, 30)),
        "radon": RadonResponse(inst, grid, 48, dtype=np.float64),
        "default": MatrixOperator(mat.matrix),  # ResponseOperator.block itself
    }
    for kind, op in ops.items():
        with pytest.raises(ParameterError, match=match):
            op.block(t=t, n=n)
        # The edges of the ranges are valid, numpy integers too.
        edge = op.block(t=(np.int64(47), 48), n=(71, np.int32(72)))
        assert edge.shape == (7, 1, 1), kind


# -------------------------------------------------- one way to compute a whole response
@pytest.mark.parametrize("time_bins", [48, 15, TimeBinning(12, "average", 3)])
def test_build_response_is_the_matrix_free_materialise(inst, grid, time_bins):
    ref = build_response(inst, grid, time_bins, "advanced-approx")
    free = MatrixFreeResponse(inst, grid, time_bins, "advanced-approx", dtype=np.float32,
                              block_size=(5, 30))
    # The same local fill (ResponsePlan.fill): bit for bit, whatever the block size.
    np.testing.assert_array_equal(free.materialise().matrix, ref.matrix)
    # The block walk (as on a cluster; here locally, with a progress bar): every value from
    # the same kernel on the same inputs, bit for bit.
    for block_size in (None, (5, 30)):
        walked = build_response(inst, grid, time_bins, "advanced-approx", progress=True,
                                block_size=block_size)
        np.testing.assert_array_equal(walked.matrix, ref.matrix)
        assert walked.metadata() == ref.metadata()


# ------------------------------------------------------ a matrix from elsewhere, described
def test_materialised_with_every_field_adopts_a_spec(inst, grid, mat):
    m = MaterialisedResponse(mat.matrix, instrument=inst, grid=grid, time_bins=48,
                             model="advanced-approx")
    assert m.spec == mat.spec and m.metadata() == mat.metadata()
    assert m.spec == ResponseSpec(inst, grid, 48, "advanced-approx", dtype=np.float64)
    # Partial metadata stays loose, checked by the spec's own validators.
    part = MaterialisedResponse(mat.matrix, grid=grid, energy=662.0)
    assert part.spec is None and part.grid is grid and part.energy == 662.0
    assert part.metadata()["grid"] == grid.to_dict() and part.metadata()["instrument"] is None
    for kwargs, message in (
        ({"energy": -1.0}, "energy must be > 0"),
        ({"instrument": "paper"}, "instrument must be an Instrument, got str"),
        ({"grid": 3}, "grid must be a sky grid"),
        ({"model": "nope"}, "model must be one of"),
        ({"time_bins": 12}, "time_bins has 12 bins but the response has n_time = 48"),
        ({"instrument": Instrument(inst.mask, DetectorArray.hexagonal(3.8, rings=2)),
          "grid": grid, "time_bins": 48, "model": "exact"},
         "instrument has 19 detectors but the response has n_det = 7"),
    ):
        with pytest.raises(ParameterError, match=message):
            MaterialisedResponse(mat.matrix, **kwargs)
