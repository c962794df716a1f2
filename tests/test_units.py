"""The units rule on every public entry point that takes an angle.

One rule (docs/conventions.md, "Units"): Quantities are accepted everywhere and a plain angle
means degrees.  Each case below calls an entry point with the same angle written four ways
(plain degrees, deg, arcmin and rad Quantities) and requires identical results to round-off,
then a length in place of the angle must raise a ParameterError that names the parameter.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import SkyCoord

from rotmod import DetectorArray, Instrument
from rotmod.binning import TimeBinning
from rotmod.cli._common import parse_source, to_number
from rotmod.errors import ParameterError
from rotmod.events import EventList, FoldedProfiles, exposure_per_bin
from rotmod.materials import PAPER_SIGMA_662
from rotmod.montecarlo import chord_lengths, simulate_profiles
from rotmod.profiles import get_model, project
from rotmod.reconstruction.metrics import localization_errors
from rotmod.sky import Attitude, PointSources, SkyGrid

INST = Instrument(Instrument.paper(sigma=PAPER_SIGMA_662).mask,
                  DetectorArray([[0.0, 0.0], [4.2, -3.0]], 4.0))
GRID = SkyGrid((9, 9), 0.5)
SKY = SkyCoord([11.0, 9.0] * u.deg, [21.0, 19.5] * u.deg)


def _plain(x: Any) -> Any:
    return x.to_value(u.rad) if isinstance(x, u.Quantity) else x


def _profile(arg: str) -> Callable[[Any], Any]:
    base = {"theta": [6.0, 20.0], "phi": [30.0, -100.0], "xi": np.linspace(0.0, 350.0, 8)}

    def call(value: Any) -> Any:
        kw = {**base, arg: value}
        return get_model("exact").profile(INST, kw["theta"], kw["phi"], kw["xi"], 662.0)

    return call


def _mc(arg: str) -> Callable[[Any], Any]:
    base = {"theta": [6.0], "phi": [30.0], "xi_edges": [0.0, 90.0, 180.0]}

    def call(value: Any) -> Any:
        kw = {**base, arg: value}
        return simulate_profiles(INST, kw["theta"], kw["phi"], xi_edges=kw["xi_edges"],
                                 energy=662.0, n_photons=200, seed=3).counts

    return call


def _event_phase(value: Any) -> Any:
    ev = EventList([1.0, 2.0], [0, 1], [662.0, 662.0], INST, [[0.0, 60.0]], start_phase=value)
    return ev.mask_angle().to_value(u.rad)


def _folded(arg: str) -> Callable[[Any], Any]:
    base = {"bin_edges": [0.0, 120.0, 240.0, 360.0], "start_phase": 30.0}

    def call(value: Any) -> Any:
        kw = {**base, arg: value}
        f = FoldedProfiles(np.ones((2, 3), int), np.full(3, 20.0),
                           TimeBinning.from_edges(kw["bin_edges"]), INST, [[0.0, 60.0]],
                           kw["start_phase"])
        return np.append(f.bin_edges.to_value(u.rad), f.start_phase.to_value(u.rad))

    return call


# (entry point, parameter, an angle in degrees to write four ways)
CASES: list[tuple[str, Callable[[Any], Any], float | list[float]]] = [
    ("profile theta", _profile("theta"), [6.0, 20.0]),
    ("profile phi", _profile("phi"), [30.0, -100.0]),
    ("profile xi", _profile("xi"), [0.0, 50.0, 100.0, 150.0, 200.0, 250.0, 300.0, 350.0]),
    ("project theta", lambda v: project(INST, v, [10.0], 662.0).X, [12.0]),
    ("project phi", lambda v: project(INST, [12.0], v, 662.0).Y, [75.0]),
    ("PointSources theta", lambda v: _plain(PointSources(v, [10.0]).theta), [3.0, 7.0]),
    ("PointSources phi", lambda v: _plain(PointSources([3.0, 7.0], v).phi), [10.0, 200.0]),
    ("from_image theta", lambda v: _plain(PointSources.from_image(v, [1.0], [2.0]).theta), [4.0]),
    ("simulate_profiles theta", _mc("theta"), [6.0]),
    ("simulate_profiles phi", _mc("phi"), [30.0]),
    ("simulate_profiles xi_edges", _mc("xi_edges"), [0.0, 90.0, 180.0]),
    ("chord_lengths theta",
     lambda v: chord_lengths(INST, -100.0, 0.0, v, 0.0, 0.0), 45.0),
    ("chord_lengths xi",
     lambda v: chord_lengths(INST, 0.0, -100.0, 45.0, 90.0, v), -90.0),
    ("EventList start_phase", _event_phase, 40.0),
    ("exposure_per_bin start_phase",
     lambda v: exposure_per_bin([[0.0, 45.0]], 6, 60.0, v), 50.0),
    ("TimeBinning.from_edges edges", _folded("bin_edges"), [0.0, 120.0, 240.0, 360.0]),
    ("FoldedProfiles start_phase", _folded("start_phase"), 30.0),
    ("SkyGrid pixel_size", lambda v: _plain(SkyGrid((3, 3), v).directions()[0]), 0.5),
    ("SkyGrid.square fov", lambda v: SkyGrid.square(v, 0.5).shape, 4.0),
    ("SkyGrid center", lambda v: _plain(SkyGrid((3, 3), 0.5, (v, 0.0)).directions()[0]), 1.5),
    ("SkyGrid tangent",
     lambda v: _plain(SkyGrid((3, 3), 0.5, tangent=(v, 30.0)).directions()[0]), 40.0),
    ("to_tangent theta", lambda v: GRID.to_tangent(v, [20.0]), [1.5]),
    ("from_tangent x", lambda v: _plain(GRID.from_tangent(v, [0.5])[0]), [1.5]),
    ("Attitude roll",
     lambda v: _plain(Attitude(10.0, 20.0, v).to_instrument(SKY)[1]), 30.0),
    ("Attitude dec", lambda v: _plain(Attitude(10.0, v, 0.0).to_instrument(SKY)[0]), 20.0),
    ("to_sky theta", lambda v: Attitude(10.0, 20.0).to_sky(v, [40.0]).ra.deg, [5.0]),
    ("localization sources",
     lambda v: localization_errors(np.eye(9), GRID, (v, [45.0]), radius=1.0), [1.0]),
]


def _four_ways(deg: float | list[float]) -> list[Any]:
    d = np.asarray(deg, dtype=float)
    plain = deg if isinstance(deg, float) else list(deg)
    return [plain, d * u.deg, (d * 60.0) * u.arcmin, np.radians(d) * u.rad]


@pytest.mark.parametrize(("name", "call", "deg"), CASES, ids=[c[0] for c in CASES])
def test_plain_angles_are_degrees_and_quantities_convert(name, call, deg) -> None:
    results = [np.asarray(call(v), dtype=float) for v in _four_ways(deg)]
    for r in results[1:]:
        # The same angle through one unit conversion (deg/arcmin/rad to rad): a few ulp.
        np.testing.assert_allclose(r, results[0], rtol=1e-12, atol=1e-12, err_msg=name)


@pytest.mark.parametrize(("name", "call", "deg"), CASES, ids=[c[0] for c in CASES])
def test_a_length_in_place_of_an_angle_names_the_parameter(name, call, deg) -> None:
    param = name.split()[-1]
    want = {"sources": "theta", "x": "x"}.get(param, param)
    with pytest.raises(ParameterError, match=rf"{want}.* must be in units of deg"):
        call(np.asarray(deg) * u.cm)


def test_error_bounds_speak_degrees() -> None:
    with pytest.raises(ParameterError, match="theta must be < 90 deg, got 95 deg"):
        get_model("exact").profile(INST, [95.0], [0.0], [0.0], 662.0)
    with pytest.raises(ParameterError, match=r"theta must be < 90 deg, got 91\.\d+ deg"):
        PointSources([1.6] * u.rad, [0.0])


def test_outputs_are_quantities_that_round_trip() -> None:
    theta, phi = GRID.directions()
    assert theta.unit == u.rad and phi.unit == u.rad
    # Handing an output back in cannot be misread as degrees.
    src = PointSources(theta[:3], phi[:3])
    np.testing.assert_array_equal(src.theta, theta[:3])
    back = PointSources.from_dict(src.to_dict())
    np.testing.assert_allclose(back.theta.to_value(u.rad), theta[:3].to_value(u.rad),
                               rtol=1e-15)


@pytest.mark.parametrize(
    ("text", "unit", "value"),
    [("3", "deg", 3.0), ("3deg", "deg", 3.0), ("30 arcmin", "deg", 0.5), ("5min", "s", 300.0),
     ("60 s", "s", 60.0), ("1.2MeV", "keV", 1200.0), ("12 mm", "cm", 1.2)],
)
def test_cli_numbers_take_units(text, unit, value) -> None:
    assert to_number(text, unit) == pytest.approx(value, rel=1e-15)


@pytest.mark.parametrize(("text", "match"), [("2kg", "must be in units of s"),
                                             ("abc", "must be a number"),
                                             ("nan", "must be finite")])
def test_cli_numbers_refuse_bad_units(text, match) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=match):
        to_number(text, "s")


def test_cli_sources_take_units() -> None:
    assert parse_source("3deg,30arcmin") == pytest.approx((3.0, 0.5))
    assert parse_source("0.1rad,0,5", with_rate=True) == pytest.approx((np.degrees(0.1), 0, 5))
    with pytest.raises(argparse.ArgumentTypeError, match="THETA,PHI"):
        parse_source("3cm,0")
