"""Debatable inputs, decided (issue 25, class 7; the decisions are in docs/reliability.md):
a mask that never passes over a detector warns, ``--tolerance`` with the matrix operator is
refused, a band with no event warns, and a non-finite sky or data is refused by every
response operator."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from rotmod import DetectorArray, Instrument, Mask, get_model
from rotmod.cli import main
from rotmod.errors import ParameterError
from rotmod.events import fold
from rotmod.montecarlo import simulate_observation
from rotmod.response import MatrixFreeResponse, RadonResponse, build_response
from rotmod.response.drift import drift_response
from rotmod.sky import Attitude, CelestialGrid, PointSources, SkyGrid

XI = np.linspace(0.0, 180.0, 36, endpoint=False)


def _offset_instrument(offset: float) -> Instrument:
    # A 10 cm disc of mask turning about an axis `offset` cm from the one 4 cm detector.
    return Instrument(Mask(4.0, 4.0, 2.0, 100.0, "lead", axis_offset_x=offset,
                           outline="circle", outline_size=10.0), DetectorArray.single(4.0))


def test_a_mask_that_never_passes_over_a_detector_warns_with_the_geometry() -> None:
    # Detector edge at 2 cm, mask reach 30 - 10 = 20 cm: 18 cm apart; the slab spans
    # L = 100 to L + h = 102 cm, so sources within atan(18 / 102) = 10.0 deg cast no shadow.
    with pytest.warns(UserWarning, match=r"mask \(circle of radius 10 cm turning about an axis "
                      r"offset by \(30, 0\) cm\) never passes over a detector: the nearest "
                      r"detector edge is 18 cm outside .* sources within 10 deg of the axis "
                      r"cast no shadow"):
        inst = _offset_instrument(30.0)
    # Independent evidence for the bound: the exact model's profiles are flat (no
    # modulation at all) for sources inside it, and modulated for one whose rays cross the
    # mask 5 cm from its centre (theta = 14 deg toward it: 100 tan(theta) = 25 cm).
    P = get_model("exact").profile(inst, [0.0, 5.0, 9.0, 14.0], [0.0] * 4, XI, energy=662)[0]
    np.testing.assert_array_equal(P[:, :3], 1.0)
    assert P[:, 3].std() > 0.1
    # A mask that does pass over the detector: no warning (filterwarnings = error), and the
    # profile of a source 2 deg off axis is modulated.
    inst = _offset_instrument(5.0)
    assert get_model("exact").profile(inst, [2.0], [0.0], XI, energy=662)[0].std() > 0.05


def test_tolerance_with_the_matrix_operator_is_refused(capsys, tmp_path) -> None:
    code = main(["response", "--fov", "2", "--pixel", "1", "-n", "12", "--tolerance", "1e-3",
                 "-o", str(tmp_path / "r.zarr")])
    err = capsys.readouterr().err
    assert code == 2 and "--tolerance: only with --operator radon" in err, err
    assert not list(tmp_path.iterdir())
    code = main(["response", "--fov", "2", "--pixel", "1", "-n", "12", "--tolerance", "1e-3",
                 "--operator", "radon", "-o", str(tmp_path / "r.zarr")])
    assert code == 0, capsys.readouterr().err
    # The library's drift response: the same rule.
    att = Attitude(10.0, 20.0)
    grid = CelestialGrid((2, 2), 1.0, 10.0, 20.0, att)
    pieces = [(0.0, 60.0, att)]
    with pytest.raises(ParameterError, match=r"tolerance: only the Radon operators interpolate"):
        drift_response(Instrument.paper(), grid, 12, pieces, energy=122, tolerance=1e-3)
    drift_response(Instrument.paper(), grid, 12, pieces, energy=122, operator="radon",
                   tolerance=1e-3)


def test_a_band_with_no_event_warns_with_the_band_and_the_events_range(caplog) -> None:
    ev = simulate_observation(Instrument.paper(), PointSources([3.0], [0.0], rate=20.0,
                                                               energy=122.0),
                              t_stop=60.0, seed=2)
    with caplog.at_level(logging.WARNING, logger="rotmod"):
        empty = fold(ev, 12, energy_band=(500.0, 600.0))
    assert empty.counts.sum() == 0
    assert ("fold: no event has an energy in the band 500-600 keV (the events in the "
            "good-time intervals span 122-122 keV); the folded counts are all 0"
            ) in caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="rotmod"):
        full = fold(ev, 12, energy_band=(100.0, 140.0))
    assert full.counts.sum() == ev.time.size and "no event" not in caplog.text


@pytest.fixture(scope="module")
def operators():
    inst = Instrument.paper()
    grid = SkyGrid((3, 3), 1.0)
    return [build_response(inst, grid, 12, energy=122),
            MatrixFreeResponse(inst, grid, 12, energy=122),
            RadonResponse(inst, grid, 12, 122)]


@pytest.mark.parametrize("k", range(3))
def test_every_operator_refuses_non_finite_skies_and_counts(operators, k) -> None:
    op = operators[k]
    # An all-NaN sky gave an all-NaN forward() (one NaN pixel already spoils every rate).
    with pytest.raises(ParameterError, match=r"sky must be finite, got nan at index 0 \(9 of "
                       r"9 values not finite\)"):
        op.forward(np.full(9, np.nan))
    sky = np.ones(9)
    sky[4] = np.inf
    with pytest.raises(ParameterError, match=r"sky must be finite, got inf at index 4"):
        op.forward(sky)
    y = np.ones((1, 12))
    y[0, 5] = np.nan
    with pytest.raises(ParameterError, match=r"counts must be finite, got nan at index \(0, 5\)"):
        op.adjoint(y)
    assert np.all(np.isfinite(op.forward(np.ones(9))))
