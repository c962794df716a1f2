"""Mask design scan: figures of merit, Pareto front (checked by brute force), best design."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from rotmod.design import pareto_front, scan_designs
from rotmod.errors import ParameterError


def brute_force_front(v: np.ndarray, maximize: list[bool]) -> np.ndarray:
    """Non-dominated rows by the definition, one pair at a time."""
    s = np.where(maximize, 1.0, -1.0)
    w = v * s
    keep = np.ones(len(w), bool)
    for i, j in itertools.product(range(len(w)), repeat=2):
        if i != j and np.all(w[j] >= w[i]) and np.any(w[j] > w[i]):
            keep[i] = False
    return keep


@pytest.fixture(scope="module")
def scan():
    # A tiny scan (3 x 3 x 2 designs, 2 energies) with thick slats, so some designs fall
    # outside the advanced model's validity over a 40 deg field.
    return scan_designs(
        detector_diameter=4.0, height=100.0, slat_width=[1.0, 4.0, 8.0],
        slat_gap=[1.0, 4.0, 8.0], thickness=[0.5, 4.0], energies=[122.0, 662.0], fov=40.0,
        n_theta=2, n_phi=2, n_angles=24,
    )


def test_pareto_front_matches_brute_force(scan) -> None:
    v = scan.objectives()
    assert np.array_equal(scan.pareto, brute_force_front(v, [True, True, False]))
    rng = np.random.default_rng(3)
    for _ in range(20):
        r = np.round(rng.random((30, 3)), 1)  # ties on purpose
        mx = [bool(b) for b in rng.integers(0, 2, 3)]
        assert np.array_equal(pareto_front(r, mx), brute_force_front(r, mx))


def test_figures_of_merit_are_sane(scan) -> None:
    assert len(scan) == 18
    assert np.all((scan.transmission > 0) & (scan.transmission <= 1))
    assert np.all(scan.sensitivity >= 0)
    assert np.allclose(scan.resolution_deg, np.degrees(np.arctan(scan.slat_gap / 100.0)))
    # Transmission grows with the gap at fixed slat width and thickness.
    sel = (scan.slat_width == 4.0) & (scan.thickness == 4.0)
    t = scan.transmission[sel][np.argsort(scan.slat_gap[sel])]
    assert np.all(np.diff(t) > 0)


def test_advanced_validity_flag(scan) -> None:
    # theta_max = 20 deg: h tan(theta) = 1.456 cm for h = 4 cm, 0.18 cm for h = 0.5 cm.
    smax = scan.thickness * np.tan(np.radians(20.0))
    expect = (scan.slat_width >= smax) & (scan.slat_gap >= smax)
    assert np.array_equal(scan.advanced_valid, expect)
    assert not scan.advanced_valid.all() and scan.advanced_valid.any()
    assert np.allclose(scan.min_a_prime, scan.slat_width - smax)


def test_best_design_weights(scan) -> None:
    i = scan.best((1, 0, 0))
    assert scan.pareto[i]
    assert scan.sensitivity[i] == scan.sensitivity[scan.pareto].max()
    j = scan.best((0, 0, 1))
    assert scan.resolution_deg[j] == scan.resolution_deg.min()
    k = scan.best((1, 1, 1), require_advanced=True)
    assert scan.advanced_valid[k]
    with pytest.raises(ParameterError, match="weights must be three numbers"):
        scan.best((1, 1))
    t = scan.to_table()
    assert {"slat_width", "sensitivity", "pareto", "advanced_valid"} <= set(t.colnames)
    assert t.meta["best_index"] == scan.best()


def test_thin_opaque_mask_prefers_a_equals_c() -> None:
    # The paper's Sec. 5: with thin opaque slats, a = b = c maximises contrast with no dead
    # time: at equal b, a = c has the largest sensitivity, and more transmission than a > c.
    s = scan_designs(detector_diameter=4.0, height=100.0, slat_width=[2.0, 4.0, 6.0],
                     slat_gap=[4.0], thickness=1e-6, mu=np.inf, energies=[100.0], fov=10.0,
                     n_theta=2, n_phi=2, n_angles=90)
    assert s.sensitivity[1] > s.sensitivity[0]
    assert s.sensitivity[1] > s.sensitivity[2]
    assert s.transmission[1] > s.transmission[2]


def test_bad_inputs() -> None:
    with pytest.raises(ParameterError, match="slat_width must be > 0"):
        scan_designs(detector_diameter=4, height=100, slat_width=[-1], slat_gap=[4],
                     thickness=1)
    with pytest.raises(ParameterError, match="fov must be < 180"):
        scan_designs(detector_diameter=4, height=100, slat_width=[4], slat_gap=[4],
                     thickness=1, fov=200)
