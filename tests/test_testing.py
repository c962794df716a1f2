"""rotmod.testing: the dot test catches a wrong adjoint, the test operator counts its products."""

from __future__ import annotations

import numpy as np
import pytest

from rotmod.errors import ParameterError
from rotmod.reconstruction import reconstruct
from rotmod.sky import SkyGrid
from rotmod.testing import MatrixOperator, dot_test, tiny_grid, tiny_instrument


class _WrongAdjoint(MatrixOperator):
    """The adjoint of another matrix: a bug the dot test must catch."""

    def _adjoint(self, counts: np.ndarray) -> np.ndarray:
        return super()._adjoint(counts) * (1.0 + 1e-6)


def _random_operator(seed: int = 0) -> MatrixOperator:
    return MatrixOperator(np.random.default_rng(seed).random((3, 10, 12)), SkyGrid((3, 4), 1.0))


def test_dot_test_passes_a_true_adjoint_to_round_off() -> None:
    op = _random_operator()
    # float64 sums of 360 positive terms: round-off ~1e-16 relative, far inside 1e-13.
    assert dot_test(op, rng=1, rtol=1e-13) < 1e-13
    # An int seeds the generator: the same x, y, the same mismatch.
    assert dot_test(op, rng=1) == dot_test(op, rng=np.random.default_rng(1))


def test_dot_test_catches_a_wrong_adjoint_naming_both_sides() -> None:
    op = _WrongAdjoint(_random_operator().P)
    assert dot_test(op, rng=2) == pytest.approx(1e-6, rel=1e-6)
    with pytest.raises(AssertionError, match=r"<P x, y> = .* but <x, P\^T y> = .*rtol 1e-09"):
        dot_test(op, rng=2, rtol=1e-9)


def test_dot_test_refuses_a_negative_rtol() -> None:
    with pytest.raises(ParameterError, match="rtol must be >= 0"):
        dot_test(_random_operator(), rtol=-1.0)


def test_matrix_operator_products_and_counters() -> None:
    op = _random_operator()
    x = np.arange(12.0)
    y = np.ones((3, 10))
    np.testing.assert_array_equal(op.forward(x), op.P @ x)
    np.testing.assert_array_equal(op.adjoint(y), np.einsum("dtn,dt->n", op.P, y))
    assert (op.n_forward, op.n_adjoint, op.calls) == (1, 1, 2)
    op.sensitivity()
    op.sensitivity()  # cached: one adjoint
    assert (op.n_forward, op.n_adjoint) == (1, 2)
    op.reset_counts()
    assert op.calls == 0
    # A reconstruction costs forward and adjoint products, and nothing else is counted.
    res = reconstruct(op, np.round(10.0 * (op.forward(x) + 1.0)), "mlem", exposure=10.0,
                      background=1.0, max_iter=4, chi2_dof=None, rel_tol=None)
    assert res.n_iter == 4 and op.n_forward >= 5 and op.n_adjoint >= 4
    assert op.spec is None


def test_matrix_operator_refuses_bad_shapes() -> None:
    with pytest.raises(ParameterError, match=r"P must have shape \(n_det, n_time, n_sky\)"):
        MatrixOperator(np.ones((4, 5)))
    with pytest.raises(ParameterError, match="grid must be a sky grid of 12 pixels"):
        MatrixOperator(np.ones((1, 2, 12)), SkyGrid((3, 3), 1.0))


def test_tiny_instrument_and_grid() -> None:
    inst = tiny_instrument()
    assert len(inst.detectors) == 7 and inst.mask.thickness == 2.0 and inst.mask.height == 100.0
    assert len(tiny_instrument(rings=0).detectors) == 1
    assert tiny_grid().shape == (11, 11) and tiny_grid().pixel_size == 0.6
