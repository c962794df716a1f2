"""``rotmod burst`` end to end: an injected burst found, localised and summarised, its files
read back by other tools, and bad inputs refused with one line and exit code 2."""

from __future__ import annotations

import contextlib
import io

import astropy.units as u
import pytest
from astropy.table import Table

from rotmod.bursts import norris_pulse, simulate_burst
from rotmod.cli import main
from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.io import write_events
from rotmod.io.regions import read_probability_map
from rotmod.sky import Attitude

#: The small fast RM of tests/bursts: 7 detectors, b/L = 5.7 deg, a 2 s turn.
INST = Instrument(Mask(3, 3, 3, 30), DetectorArray.hexagonal(5, rings=1), rotation_period=2.0)
ATT = Attitude(120.0, -30.0, 20.0)
TRUTH = ATT.to_sky(15.0 * u.deg, 130.0 * u.deg)


@pytest.fixture(scope="module")
def event_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("burst") / "events.fits"
    ev = simulate_burst(INST, TRUTH, lambda t: norris_pulse(t, 50.0, 0.3, 2.0, 60.0),
                        t_start=0.0, t_stop=120.0, background=2.0, energy=300.0,
                        attitude=ATT, seed=11)
    write_events(ev, path)
    return path


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(argv))
    return code, out.getvalue(), err.getvalue()


def test_burst_found_and_written(event_file, tmp_path):
    prefix = tmp_path / "grb"
    code, out, err = _run("burst", str(event_file), "-e", "300", "--radius", "40",
                          "-o", str(prefix))
    assert code == 0, err
    assert "1 candidate" in err and "T90" in out
    row = Table.read(f"{prefix}_1.fits", hdu="BURST")
    assert row["r90"].unit == u.deg and row["sqrt_ts"][0] > 10
    prob = read_probability_map(f"{prefix}_1_prob.fits")
    assert abs(float(prob.prob.sum()) - 1.0) < 1e-9
    assert (tmp_path / "grb_1.png").stat().st_size > 0
    assert "T90" in (tmp_path / "grb_1.txt").read_text()
    # A second run refuses to overwrite without --overwrite.
    code, _, err = _run("burst", str(event_file), "-e", "300", "--radius", "40",
                        "-o", str(prefix))
    assert code == 2 and "already exists" in err


@pytest.mark.parametrize(("args", "message"), [
    (["--far", "0"], "--far"),
    (["--far", "x/y"], "--far"),
    (["--radius", "95"], "--radius"),
    (["--systematic", "-1"], "--systematic"),
    (["--interval", "5"], "--interval"),
    (["--max-step", "0"], "--max-step"),
    (["-i", "paper"], "--instrument"),
])
def test_bad_options_are_refused(event_file, tmp_path, args, message):
    code, _, err = _run("burst", str(event_file), "-e", "300", "-o", str(tmp_path / "b"),
                        *args)
    assert code == 2 and message in err and "Traceback" not in err


def test_no_burst_is_a_clear_answer(event_file, tmp_path):
    code, _, err = _run("burst", str(event_file), "-e", "300", "--radius", "40",
                        "--interval", "110,115", "-o", str(tmp_path / "b"))
    assert code == 0 and "not analysed" in err and "no block" in err


def test_an_interrupt_exits_130_and_writes_nothing(event_file, tmp_path, monkeypatch):
    # Ctrl-C during the analysis (the long step): the command stops with the shell's code
    # for SIGINT and leaves no file of the burst behind, not even a partial one.
    import rotmod.cli._burst as cli_burst

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli_burst, "analyse_burst", interrupted)
    code, _, err = _run("burst", str(event_file), "-e", "300", "--radius", "40",
                        "-o", str(tmp_path / "grb"))
    assert code == 130 and "interrupted" in err
    assert list(tmp_path.iterdir()) == []
