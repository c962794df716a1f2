"""rotmod.io.read / rotmod.io.write: every format through one door, the one overwrite policy."""

from __future__ import annotations

import numpy as np
import pytest

import rotmod.io as rio
from rotmod import DetectorArray, Instrument, Mask, Material
from rotmod.config import InstrumentConfig
from rotmod.errors import ParameterError
from rotmod.events import EventList, FoldedProfiles, fold
from rotmod.io import list_presets, load_instrument_config
from rotmod.montecarlo import simulate_observation
from rotmod.sky import AttitudeTable, PointSources


@pytest.fixture(scope="module")
def events() -> EventList:
    mat = Material("Pb", density=11.34, mass_attenuation=0.103)
    inst = Instrument(Mask(4.0, 4.0, 2.0, 100.0, mat), DetectorArray.single(4.0), 30.0)
    src = PointSources([6.0], [0.3], rate=[40.0], energy=662.0)
    return simulate_observation(inst, src, t_stop=50.0, seed=3)


def test_event_lists_and_folded_profiles_through_the_registry(events, tmp_path) -> None:
    p = rio.write(events, tmp_path / "ev.fits")
    back = rio.read(p)  # the file says what it holds: an EVENTS extension
    assert isinstance(back, EventList) and np.array_equal(back.time, events.time)
    f = fold(events, 12)
    q = rio.write(f, tmp_path / "f.fits")
    back_f = rio.read(q)
    assert isinstance(back_f, FoldedProfiles) and np.array_equal(back_f.counts, f.counts)
    assert isinstance(rio.read(q, cls=FoldedProfiles), FoldedProfiles)


@pytest.mark.parametrize("name", list_presets())
def test_every_preset_round_trips_through_a_toml_file(name, tmp_path) -> None:
    cfg = load_instrument_config(name)
    path = rio.write(cfg, tmp_path / f"{name}.toml")
    assert rio.read(path) == cfg
    assert InstrumentConfig.read(path) == cfg


def test_attitude_tables_refuse_to_overwrite_and_write_atomically(tmp_path) -> None:
    table = AttitudeTable([0.0, 60.0], [10.0, 10.5], [20.0, 20.2], [0.0, 5.0])
    path = tmp_path / "aspect.ecsv"
    rio.write(table, path)
    with pytest.raises(ParameterError, match=r"already exists; pass overwrite=True"):
        table.write(path)
    with pytest.raises(ParameterError, match=r"already exists; pass overwrite=True"):
        rio.write(table, path)
    table.write(path, overwrite=True)
    np.testing.assert_array_equal(rio.read(path, cls=AttitudeTable).roll, table.roll)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["aspect.ecsv"]  # no temporary left


def test_unknown_classes_formats_and_extensions_list_what_is_registered(tmp_path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(ParameterError, match=r"obj: no writer is registered for builtins\.int; "
                       r"writers: .*EventList \(fits"):
        rio.write(3, out / "x.fits")
    cfg = load_instrument_config("paper")
    with pytest.raises(ParameterError, match=r"extension names no format .*\.toml \(toml\)"):
        rio.write(cfg, out / "x.txt")
    with pytest.raises(ParameterError, match=r"format 'yaml' of .* is read-only"):
        rio.write(cfg, out / "x.yaml", format="yaml")
    assert not list(out.iterdir())  # every refusal came before any file was made
    toml, unknown = tmp_path / "x.toml", tmp_path / "x.unknown"
    toml.touch()
    unknown.touch()
    with pytest.raises(ParameterError, match=r"format must be one of \['toml', 'yaml'\]"):
        rio.read(toml, cls=InstrumentConfig, format="tmol")
    with pytest.raises(ParameterError, match=r"cls: no reader is registered for builtins\.int"):
        rio.read(toml, cls=int)
    with pytest.raises(ParameterError, match=r"no registered reader matches it"):
        rio.read(unknown)
    # A missing path is said first, before any guess at what it might have held.
    with pytest.raises(ParameterError, match=r"x\.fits' does not exist"):
        rio.read(tmp_path / "x.fits")
    with pytest.raises(ParameterError, match=r"out' is not a file"):
        rio.read(out)


def test_a_format_is_registered_once() -> None:
    with pytest.raises(ParameterError, match="registered already"):
        rio.register(EventList, "fits", reader=rio.read_events)
