"""Geometry objects, their validation and the sign conventions (checked by ray tracing)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rotmod.conventions import mask_coordinate, shadow_shift, source_direction
from rotmod.errors import ParameterError
from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.profiles import project
from tests.conftest import rad


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"slat_width": -4.0}, "mask.slat_width must be >= 0 cm, got -4 cm"),
        ({"slat_gap": -1.0}, "mask.slat_gap must be >= 0"),
        ({"slat_width": 0.0, "slat_gap": 0.0}, r"mask.slat_width \+ mask.slat_gap must be > 0"),
        ({"thickness": -0.1}, "mask.thickness must be >= 0"),
        ({"height": 0.0}, "mask.height must be > 0"),
        ({"slat_width": np.nan}, "mask.slat_width must be finite"),
        ({"mu": -1.0}, "mask.mu must be >= 0"),
        ({"material": 3}, "mask.material must be a Material or a name"),
    ],
)
def test_mask_validation(kwargs, match):
    args = {"slat_width": 4.0, "slat_gap": 4.0, "thickness": 2.0, "height": 100.0}
    args.update(kwargs)
    with pytest.raises(ParameterError, match=match):
        Mask(**args)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: DetectorArray.single(0.0), "detectors.diameter must be > 0"),
        (lambda: DetectorArray.single(-3.8), "detectors.diameter must be > 0"),
        (lambda: DetectorArray.single(np.nan), "detectors.diameter must be finite"),
        (lambda: DetectorArray(np.zeros((2, 3)), 1.0), r"shape \(n, 2\)"),
        (lambda: DetectorArray.hexagonal(3.8, pitch=3.0), "pitch must be >= detectors.diameter"),
        (lambda: DetectorArray.hexagonal(3.8, rings=-1), "rings must be an integer >= 0"),
        (lambda: Instrument("mask", DetectorArray.single(4.0)), "instrument.mask must be"),
    ],
)
def test_detector_and_instrument_validation(call, match):
    with pytest.raises(ParameterError, match=match):
        call()


def test_hexagonal_prototype_and_roundtrip():
    det = DetectorArray.hexagonal(3.8)
    assert len(det) == 19
    d = np.hypot(*(det.positions[:, None, :] - det.positions[None, :, :]).transpose(2, 0, 1))
    assert d[d > 0].min() == pytest.approx(1.05 * 3.8)
    assert np.allclose(det.positions[0], 0.0)
    inst = Instrument(Mask(4.0, 4.0, 2.0, 100.0, "Pb"), det, rotation_period=30.0)
    assert Instrument.from_dict(inst.to_dict()) == inst
    assert inst.mask_angle(7.5).to_value("rad") == pytest.approx(np.pi / 2)


def test_slat_layout_gap_on_axis():
    m = Mask(3.0, 2.0, 1.0, 50.0, mu=1.0)
    # Gap centred on u = 0 (|u| < b/2), slats from b/2 to b/2 + a, period a + b.
    assert np.all(m.slat_fraction([0.0, 0.99, -0.99, 4.5, 2.0]) == [0, 0, 0, 0, 1])
    assert np.all(m.slat_fraction([1.0, 3.9, -1.1, -4.0]) == 1)
    assert m.open_fraction == pytest.approx(0.4)


def test_conventions_by_ray_tracing(rng):
    # Trace rays from a source direction through the slab and compare with the closed forms
    # of conventions.py and base.project: they are the same algebra, so round-off (1e-12).
    h, L = 2.5, 80.0
    inst = Instrument(Mask(4.0, 4.0, h, L, mu=1.0), DetectorArray([[3.0, -1.5]], 4.0))
    for _ in range(20):
        theta, phi, xi = rng.uniform(0, 1.3), rng.uniform(-np.pi, np.pi), rng.uniform(0, 7)
        d = source_direction(theta, phi)
        x0, y0 = inst.detectors.positions[0]
        bottom = np.array([x0, y0, 0.0]) + d * (L / d[2])  # where the ray crosses z = L
        top = np.array([x0, y0, 0.0]) + d * ((L + h) / d[2])
        u_bottom = mask_coordinate(bottom[0], bottom[1], xi)
        u_top = mask_coordinate(top[0], top[1], xi)
        assert u_top - u_bottom == pytest.approx(shadow_shift(h, theta, phi, xi), abs=1e-12)
        # The mask turns clockwise: u = r cos(psi + xi) for a point at polar (r, psi).
        r, psi = math.hypot(*bottom[:2]), math.atan2(bottom[1], bottom[0])
        assert u_bottom == pytest.approx(r * math.cos(psi + xi), abs=1e-12)
        geom = project(inst, rad([theta]), rad([phi]))
        uc, s = geom.mask_coordinates(np.array([xi]))
        assert uc[0, 0, 0] == pytest.approx(u_bottom, abs=1e-12)
        assert s[0, 0] == pytest.approx(u_top - u_bottom, abs=1e-12)
        assert geom.tau[0] == pytest.approx(1.0 * h / math.cos(theta))


def test_paper_instrument_is_the_paper_preset() -> None:
    # Instrument.paper holds the paper's numbers itself (geometry reads no files); the preset
    # file describes the same instrument, value for value.
    from rotmod.io import load_instrument

    preset, paper = load_instrument("paper"), Instrument.paper()
    assert paper == preset
    assert paper.to_dict() == preset.to_dict()
    assert paper.mask.material == preset.mask.material
