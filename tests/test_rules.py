"""Small rules of the structure refactor: models restored from a description through the
registry alone, the one source direction, the one energy rule."""

from __future__ import annotations

import astropy.units as u
import numpy as np
import pytest

from rotmod.conventions import source_angles, source_direction
from rotmod.errors import ParameterError
from rotmod.profiles import MODELS, AdvancedModel, StandardModel, get_model
from rotmod.response.spec import restore_fields
from rotmod.sky import Attitude, PointSources


@pytest.mark.parametrize("model", [StandardModel(0.25), StandardModel(), AdvancedModel("approx"),
                                   *(get_model(n) for n in MODELS.names())])
def test_models_restore_from_their_description(model) -> None:
    restored = restore_fields({"model": model.describe()})["model"]
    assert type(restored) is type(model) and restored.describe() == model.describe()


@pytest.mark.parametrize("desc", [{"model": "no-such-model"},
                                  {"model": "standard", "transmission": 0.1, "colour": "red"}])
def test_unknown_descriptions_restore_to_none(desc) -> None:
    assert restore_fields({"model": desc})["model"] is None


def test_attitude_round_trip_through_source_direction() -> None:
    att = Attitude(83.6 * u.deg, 22.0 * u.deg, 17.0 * u.deg)
    th = np.array([0.0, 5.0, 30.0, 80.0])
    ph = np.array([0.0, 45.0, -120.0, 170.0])
    t2, p2 = att.to_instrument(att.to_sky(th, ph))
    d1 = source_direction(np.radians(th), np.radians(ph))
    d2 = source_direction(t2.to_value(u.rad), p2.to_value(u.rad))
    assert np.allclose(d1, d2, atol=1e-12)
    # source_angles inverts source_direction
    t3, p3 = source_angles(d1)
    assert np.allclose(source_direction(t3, p3), d1, atol=1e-15)


def test_point_source_energies_follow_the_energy_rule() -> None:
    with pytest.raises(ParameterError, match=r"energy must be > 0 keV, got -1 keV"):
        PointSources([10.0], [0.0], energy=-1.0)
    s = PointSources([10.0], [0.0], energy=0.662 * u.MeV)
    assert s.energy[0] == pytest.approx(662.0)
