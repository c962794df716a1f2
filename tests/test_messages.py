"""Messages that say what is wrong (issue 25, class 6; docs/reliability.md, "Messages"):
each case once gave a message about something else."""

from __future__ import annotations

import os

import numpy as np
import pytest

from rotmod import Instrument
from rotmod.cli import main
from rotmod.config import ConfigError
from rotmod.errors import ParameterError
from rotmod.io import response_store as fmt
from rotmod.io import write_events
from rotmod.io.atomic import NAME_MAX, sibling
from rotmod.io.config import load_instrument_config, preset_path
from rotmod.montecarlo import simulate_observation
from rotmod.response import write_response
from rotmod.sky import PointSources, SkyGrid


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


def test_a_partial_store_that_is_not_rotmods_is_named_and_kept(capsys, tmp_path) -> None:
    # A folder where the unfinished store goes, with no rotmod metadata (a run killed before
    # it wrote any, or the user's): zarr said "No group found"; now what it is and what to do,
    # and the folder is left alone.
    stale = tmp_path / "r.zarr.partial"
    stale.mkdir()
    (stale / "notes.txt").write_text("mine")
    code, err = _cli(capsys, "response", "-i", "paper", "--fov", "2", "--pixel", "1", "-n", "12",
                     "-o", tmp_path / "r.zarr")
    last = err.strip().splitlines()[-1]
    assert code == 2 and "No group found" not in err, err
    assert f"'{stale}' is where the unfinished store is written, but it holds no unfinished " \
        "rotmod response" in last and "remove it, or write the store under another name" in last
    with pytest.raises(ParameterError, match="holds no unfinished rotmod response"):
        write_response(tmp_path / "r.zarr", Instrument.paper(), SkyGrid((2, 2), 1.0), 12,
                       energy=122.0)
    assert (stale / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.zarr.partial"]


def test_an_unfinished_store_without_its_array_is_named(tmp_path) -> None:
    # rotmod's metadata but no array P (an unfinished Radon table's store): a KeyError 'P'
    # (exit 1, "a bug") before; a new dense store's .partial form is now made whole before
    # it gets its name, so an interrupted start cannot leave one.
    partial = tmp_path / "r.zarr.partial"
    fmt.write_table(partial, {"shape": [1, 2]}, np.full((2, 3), 0.5))
    with pytest.raises(ParameterError, match="is an unfinished rotmod store with nothing to "
                       "resume"):
        write_response(tmp_path / "r.zarr", Instrument.paper(), SkyGrid((2, 2), 1.0), 12,
                       energy=122.0)


def test_names_near_the_length_limit_are_written(capsys, tmp_path) -> None:
    # A 250-character output: its temporary name (and a store's .partial and .lock) used to
    # pass 255 bytes.  Now they keep a shortened start of the name (and a hash, for the
    # fixed ones), and the output gets its full name.
    ev = simulate_observation(Instrument.paper(), PointSources([3.0], [0.0], 5.0, 122.0),
                              t_stop=20.0, seed=1)
    write_events(ev, tmp_path / "ev.fits")
    long_file = "f" * 245 + ".fits"
    long_store = "é" * 123 + ".zarr"  # 251 bytes in UTF-8: a character is never cut in two
    assert main([str(a) for a in ("-q", "fold", tmp_path / "ev.fits", "-n", "12", "-o",
                                  tmp_path / long_file, "--plot", tmp_path / (long_file[:-5]
                                                                            + ".png"))]) == 0
    assert main([str(a) for a in ("-q", "response", "-i", "paper", "--fov", "2", "--pixel",
                                  "1", "-n", "12", "-o", tmp_path / long_store)]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["ev.fits", long_file, long_file[:-5] + ".png", long_store])


def test_fixed_sibling_names_fit_and_differ() -> None:
    for name in ("a" * 250, "a" * 249 + "b", "é" * 125 + ".zarr"):
        p = sibling(f"/x/{name}", ".partial")
        assert len(os.fsencode(p.name)) <= NAME_MAX and p.name.endswith(".partial")
        p.name.encode("utf-8")  # whole characters only
    assert sibling("/x/" + "a" * 250, ".lock") != sibling("/x/" + "a" * 249 + "b", ".lock")
    assert sibling("/x/r.zarr", ".partial").name == "r.zarr.partial"  # short: as before


@pytest.mark.parametrize("option", ["--a", "--b", "--h", "--energies"])
@pytest.mark.parametrize("value", ["", ",", " , "])
def test_an_empty_list_is_named_as_such(capsys, tmp_path, option, value) -> None:
    # It used to scan nothing and report the advanced model's validity.
    code, err = _cli(capsys, "design", f"{option}={value}", "-o", tmp_path / "d.ecsv")
    assert code == 2
    assert f"argument {option}: an empty list" in err.strip().splitlines()[-1], err


def test_an_instrument_folder_is_called_a_folder(capsys, tmp_path) -> None:
    (tmp_path / "inst").mkdir()
    with pytest.raises(ConfigError, match=r"'.*inst' is a folder; give an instrument file"):
        load_instrument_config(tmp_path / "inst")
    code, err = _cli(capsys, "profile", "-i", tmp_path / "inst", "-s", "3,0", "-o",
                     tmp_path / "p.ecsv")
    assert code == 2 and "is a folder" in err and "does not exist" not in err, err


def test_a_missing_detector_material_table_is_named(tmp_path) -> None:
    text = preset_path("prototype").read_text()
    assert "[detectors]" in text and "detector_material" not in text
    path = tmp_path / "thick.toml"
    path.write_text(text.replace("[detectors]", '[detectors]\nthickness = "2 cm"'))
    with pytest.raises(ConfigError) as info:
        load_instrument_config(path)
    msg = str(info.value)
    assert "the [detector_material] table is required with detectors.thickness" in msg, msg
    assert "detectors.material" not in msg
    # With the table, the same file loads.
    path.write_text(path.read_text()
                    + '\n[detector_material]\nname = "NaI"\ndensity = "3.67 g/cm3"\n')
    assert load_instrument_config(path).instrument.detectors.thickness == 2.0
