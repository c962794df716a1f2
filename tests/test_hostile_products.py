"""Hostile input on the products (issue 25): catalogue files, burst event streams, OGIP spectra
and spectral models.

Every case is a mistake a user can type or a file they can be given.  Each must end in one
line naming the parameter (or file, column, card) and the rule -- ``rotmod: error: ...`` with
exit status 2 on the command line, a :class:`~rotmod.errors.RotmodError` from the library --
never a traceback, a hang, a silent NaN or wrong value, and never a changed input file (every
CLI case byte-compares its inputs before and after).

Cases whose fix belongs in code other sessions are editing (``rotmod.bursts``,
``rotmod.spectral``, ``rotmod.sources.spectra``) are marked ``xfail(strict=True)`` with the
root in the reason: they pass, and the marker must go, once that code refuses them.
docs/reliability.md ("Hostile inputs on the products") counts them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import signal
from pathlib import Path

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import SkyCoord
from astropy.io import fits
from astropy.table import Table
from scipy import integrate

from rotmod import energy as photons
from rotmod.bursts import durations, fit_background, norris_pulse, search, simulate_burst
from rotmod.cli import main
from rotmod.errors import ParameterError, RotmodError
from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.io import write_events
from rotmod.io.catalogue import read_catalogue
from rotmod.io.ogip import ogip_paths, read_ogip, write_ogip
from rotmod.limits import MemoryBudgetError, TimeBudgetError
from rotmod.montecarlo import simulate_observation
from rotmod.sky import Attitude
from rotmod.sources import PointSource, SkyModel
from rotmod.sources.spectra import SpectralColumns, extract_spectrum, fit_spectra
from rotmod.spectral import Band, CountsSpectrum, CutoffPowerLaw, PowerLaw, fit_spectrum
from tests.io.conftest import ogip_spectrum

#: The small fast RM of tests/bursts: 7 detectors, b/L = 5.7 deg, a 2 s turn.
INSTRUMENT = Instrument(Mask(3, 3, 3, 30), DetectorArray.hexagonal(5, rings=1),
                        rotation_period=2.0)
ATTITUDE = Attitude(120.0, -30.0, 20.0)


def _cli(*argv: object) -> tuple[int, str]:
    """``rotmod ARGV`` in-process: the exit code and stderr."""
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, err.getvalue()


def _snapshot(folder: Path) -> dict[Path, bytes]:
    return {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def _refused(folder: Path, argv: list[object], match: str) -> None:
    """The command exits 2 with one ``rotmod: error`` line holding ``match``, no traceback,
    and leaves every file of ``folder`` (its inputs) as it was, writing nothing new."""
    before = _snapshot(folder)
    code, err = _cli(*argv)
    last = err.strip().splitlines()[-1] if err.strip() else ""
    assert code == 2, err
    assert "Traceback" not in err
    assert last.startswith(("rotmod: error: ", "rotmod ")) and "error" in last, err
    assert match in last, err
    assert _snapshot(folder) == before


@contextlib.contextmanager
def _within(seconds: int):
    """Raise TimeoutError if the block runs longer than ``seconds`` (a hang is a failure)."""
    def stop(*_):
        raise TimeoutError(f"no answer within {seconds} s")
    old = signal.signal(signal.SIGALRM, stop)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


# -- catalogue files ------------------------------------------------------------------------


def _table(path: Path, **columns) -> Path:
    t = Table()
    for name, values in columns.items():
        t[name] = values
    t.write(path)
    return path


CATALOGUES = {
    "no positions": ({"NAME": ["a"], "FLUX": [1.0]}, "needs position columns RA and DEC"),
    "RA without DEC": ({"RA": [1.0]}, "needs position columns RA and DEC"),
    "NaN RA": ({"RA": [np.nan], "DEC": [1.0]}, "the position of row 0 is not finite"),
    "inf DEC": ({"RA": [1.0], "DEC": [np.inf]}, "the position of row 0 is not finite"),
    "NaN THETA": ({"THETA": [np.nan], "PHI": [1.0]}, "the position of row 0 is not finite"),
    "DEC 95": ({"RA": [1.0], "DEC": [95.0]}, "DEC of row 0 must be in [-90, 90] deg"),
    # RA 400 wrapped silently onto RA 40 (another source); 1e30 onto 0.
    "RA 400": ({"RA": [10.0, 400.0], "DEC": [1.0, 1.0]}, "RA of row 1 must be in [0, 360] deg"),
    "RA 1e30": ({"RA": [1e30], "DEC": [1.0]}, "RA of row 0 must be in [0, 360] deg"),
    "RA -10": ({"RA": [-10.0], "DEC": [1.0]}, "RA of row 0 must be in [0, 360] deg"),
    # Two sources of one name: a light curve's columns and --prob-maps files collided.
    "duplicated names": ({"NAME": ["A", "B", "A"], "RA": [1.0, 2.0, 3.0],
                          "DEC": [1.0, 2.0, 3.0]},
                         "the names must differ, got 'A' in rows 0 and 2"),
    "RA and ra": ({"RA": [1.0], "ra": [2.0], "DEC": [1.0]},
                  "columns RA and ra differ only in case"),
    "RA in metres": ({"RA": [1.0] * u.m, "DEC": [1.0] * u.deg},
                     "column RA must be in units of deg, got m"),
    "FLUX in erg": ({"RA": [1.0], "DEC": [1.0], "FLUX": [1.0] * u.erg},
                    "column FLUX must be in units of 1 / s, got erg"),
    # An infinite flux became a start flux of 0 in the sky model.
    "FLUX inf": ({"RA": [1.0], "DEC": [1.0], "FLUX": [np.inf]}, "FLUX of row 0 must be finite"),
    "RA strings": ({"RA": ["12:00:00"], "DEC": [1.0]}, "column RA must hold numbers"),
    "RA vector": ({"RA": [[1.0, 2.0]], "DEC": [[1.0, 2.0]]},
                  "column RA must hold one number per row"),
    "FLUX strings": ({"RA": [1.0], "DEC": [1.0], "FLUX": ["x"]}, "column FLUX must hold numbers"),
}


@pytest.mark.parametrize("ext", [".fits", ".ecsv"])
@pytest.mark.parametrize("case", sorted(CATALOGUES))
def test_catalogue_tables_refused(tmp_path, case, ext) -> None:
    columns, match = CATALOGUES[case]
    path = _table(tmp_path / f"cat{ext}", **columns)
    raw = path.read_bytes()
    with pytest.raises(ParameterError, match=f"path '{path}'") as info:
        read_catalogue(path)
    assert match in str(info.value)
    assert path.read_bytes() == raw


def test_catalogue_values_accepted_as_given(tmp_path) -> None:
    """What is valid stays valid: RA 0 and 360, DEC +-90, empty names repeated, NaN flux
    (none given), an hour-angle unit converted (1 h = 15 deg exactly)."""
    path = _table(tmp_path / "ok.ecsv", NAME=["", "", "x"], RA=[0.0, 360.0, 1.0] * u.hourangle,
                  DEC=[-90.0, 90.0, 0.0] * u.deg, FLUX=[np.nan, 1.0, 2.0])
    with pytest.raises(ParameterError, match="RA of row 1 must be in"):  # 360 h = 5400 deg
        read_catalogue(path)
    path = _table(tmp_path / "ok2.ecsv", NAME=["", "", "x"], RA=[0.0, 24.0, 1.0] * u.hourangle,
                  DEC=[-90.0, 90.0, 0.0] * u.deg, FLUX=[np.nan, 1.0, 2.0])
    cat = read_catalogue(path)
    assert cat.names == ("", "", "x")
    np.testing.assert_array_equal(cat.positions.dec.deg, [-90.0, 90.0, 0.0])
    # 1 h = 15 deg; the ICRS round trip of SkyCoord costs an ulp or two.
    assert cat.positions.ra.deg[2] == pytest.approx(15.0, rel=1e-14)
    assert np.isnan(cat.flux[0]) and cat.flux[2] == 2.0


def _catalogue_files(folder: Path) -> dict[str, Path]:
    good = Table({"RA": [1.0], "DEC": [1.0]})
    raw = (folder / "good.fits")
    good.write(raw)
    data = raw.read_bytes()
    (folder / "trunc.fits").write_bytes(data[: len(data) // 2])
    (folder / "empty.fits").write_bytes(b"")
    (folder / "text.fits").write_text("RA DEC\n1 2\n")
    (folder / "garbage.ecsv").write_text("hello\n")
    (folder / "cat.csv").write_text("RA,DEC\n1,2\n")
    (folder / "folder.fits").mkdir()
    fits.HDUList([fits.PrimaryHDU(), fits.ImageHDU(np.zeros(3), name="CATALOG")]).writeto(
        folder / "image.fits")
    fits.HDUList([fits.PrimaryHDU(np.zeros(3))]).writeto(folder / "primary.fits")
    return {k: folder / k for k in ("trunc.fits", "empty.fits", "text.fits", "garbage.ecsv",
                                    "cat.csv", "folder.fits", "image.fits", "primary.fits",
                                    "missing.fits")}


@pytest.mark.parametrize(("name", "match"), [
    ("trunc.fits", "is truncated or corrupt"),
    ("empty.fits", "is not a readable FITS file"),
    ("text.fits", "is not a readable FITS file"),
    ("garbage.ecsv", "is not a readable ECSV table"),
    ("cat.csv", "must end with .fits, .fits.gz, .ecsv"),
    ("folder.fits", "is a folder; give a catalogue file"),  # was "does not exist"
    ("image.fits", "the CATALOG extension must be a table, got ImageHDU"),  # was astropy's
    ("primary.fits", "has no table"),
    ("missing.fits", "does not exist"),
])
def test_catalogue_files_refused(tmp_path, name, match) -> None:
    files = _catalogue_files(tmp_path)
    before = _snapshot(tmp_path)
    with pytest.raises(RotmodError, match=match):
        read_catalogue(files[name])
    assert _snapshot(tmp_path) == before


@pytest.fixture(scope="module")
def sky_events(tmp_path_factory) -> Path:
    """600 s of a 1 deg source on a flat background, with the pointing, and catalogues."""
    folder = tmp_path_factory.mktemp("sky")
    inst = Instrument(Mask(3, 3, 3, 100), DetectorArray.hexagonal(5, rings=1),
                      rotation_period=60)
    att = Attitude(83.6, 22.0, 30.0)
    src = SkyCoord(84.5 * u.deg, 23.5 * u.deg)
    sources = SkyModel([PointSource(src, flux=0.5)]).point_sources(300.0, att)
    ev = simulate_observation(inst, sources, t_stop=600.0, background=2.0, seed=3,
                              attitude=att)
    write_events(ev, folder / "ev.fits")
    _table(folder / "good.ecsv", NAME=["A"], RA=[84.5], DEC=[23.5])
    _table(folder / "dup.ecsv", NAME=["A", "A"], RA=[84.5, 83.0], DEC=[23.5, 22.0])
    _table(folder / "ra444.ecsv", NAME=["A"], RA=[444.5], DEC=[23.5])
    _table(folder / "fluxinf.ecsv", NAME=["A"], RA=[84.5], DEC=[23.5], FLUX=[np.inf])
    _table(folder / "zero.ecsv", RA=np.zeros(0), DEC=np.zeros(0))
    return folder


GRID = ["-e", "300", "-m", "exact", "-n", "12", "--grid", "celestial", "--fov", "4",
        "--pixel", "1", "--no-progress"]
LC = ["-e", "300", "-m", "exact", "-n", "12", "--no-progress"]


@pytest.mark.parametrize(("argv", "match"), [
    # Catalogues that were used as given (exit 0): a wrapped RA, two sources of one name, an
    # infinite start flux made 0.
    (["detect", "{f}/ev.fits", *GRID, "-o", "{f}/o.fits", "--catalogue-in", "{f}/ra444.ecsv"],
     "RA of row 0 must be in [0, 360] deg, got 444.5"),
    (["detect", "{f}/ev.fits", *GRID, "-o", "{f}/o.fits", "--catalogue-in", "{f}/dup.ecsv"],
     "the names must differ"),
    (["detect", "{f}/ev.fits", *GRID, "-o", "{f}/o.fits", "--catalogue-in",
      "{f}/fluxinf.ecsv"], "FLUX of row 0 must be finite"),
    (["lightcurve", "{f}/ev.fits", "{f}/dup.ecsv", *LC, "--intervals", "2", "-o",
      "{f}/lc.fits"], "the names must differ"),
    (["lightcurve", "{f}/ev.fits", "{f}/ra444.ecsv", *LC, "--intervals", "2", "-o",
      "{f}/lc.fits"], "RA of row 0 must be in [0, 360] deg"),
    # Intervals wholly outside the data wrote a light curve of NaN rows (exit 0).
    (["lightcurve", "{f}/ev.fits", "{f}/good.ecsv", *LC, "--edges", "1e9,2e9", "-o",
      "{f}/lc.fits"], "--edges: no interval overlaps the events' good time (0 .. 600 s)"),
    # A billion intervals were allocated until the kernel killed the process.
    (["lightcurve", "{f}/ev.fits", "{f}/good.ecsv", *LC, "--intervals", "1e12", "-o",
      "{f}/lc.fits"], "a light curve of 1000000000000 intervals x 1 source(s) needs"),
    # Held already; kept so that they stay held.
    (["lightcurve", "{f}/ev.fits", "{f}/zero.ecsv", *LC, "--intervals", "2", "-o",
      "{f}/lc.fits"], "has no sources"),
    (["lightcurve", "{f}/ev.fits", "{f}/good.ecsv", *LC, "--edges", "nan,100", "-o",
      "{f}/lc.fits"], "--edges: must be times"),
    (["lightcurve", "{f}/ev.fits", "{f}/good.ecsv", *LC, "--edges", "5,5", "-o",
      "{f}/lc.fits"], "--edges: must be at least two increasing times"),
    (["detect", "{f}/ev.fits", *GRID, "-o", "{f}/o.fits", "--threshold", "nan"],
     "--threshold: must be a TS > 0"),
    (["detect", "{f}/ev.fits", *GRID, "-o", "{f}/o.fits", "--systematic", "inf"],
     "argument --systematic: must be finite"),
    (["detect", "{f}/ev.fits", *GRID, "-o", "{f}/o.fits", "--ul-confidence", "1.5"],
     "--ul-confidence: must be in (0.5, 1)"),
    (["detect", "{f}/ev.fits", *GRID, "-o", "{f}/o.fits", "--exact-above", "-5"],
     "exact_above must be >= 0"),
    (["detect", "{f}/ev.fits", *GRID, "-o", "{f}/o.fits", "--max-sources", "1.5"],
     "argument --max-sources: must be an integer >= 0"),
    (["detect", "{f}/ev.fits", *GRID, "-o", "{f}/o.fits", "--catalogue-in", "{f}/none.fits"],
     "--catalogue-in '{f}/none.fits' does not exist"),
])
def test_catalogue_commands_refuse(sky_events, argv, match) -> None:
    f = sky_events
    _refused(f, [str(a).format(f=f) for a in argv], match.format(f=f))


# -- burst event streams --------------------------------------------------------------------


@pytest.fixture(scope="module")
def burst_events(tmp_path_factory):
    """120 s of 7 detectors at 2 counts/s each, a burst at 50 s, and damaged copies."""
    folder = tmp_path_factory.mktemp("burst")
    truth = ATTITUDE.to_sky(15.0 * u.deg, 130.0 * u.deg)
    ev = simulate_burst(INSTRUMENT, truth, lambda t: norris_pulse(t, 50.0, 0.3, 2.0, 60.0),
                        t_start=0.0, t_stop=120.0, background=2.0, energy=300.0,
                        attitude=ATTITUDE, seed=11)
    write_events(ev, folder / "ev.fits")
    write_events(dataclasses.replace(ev, time=np.zeros(0), detector=np.zeros(0, int),
                                     energy=np.zeros(0), source=None), folder / "empty.fits")

    def damaged(name, change):
        with fits.open(folder / "ev.fits") as hl:
            hl.readall()
            change(hl)
            hl.writeto(folder / name, checksum=True)  # valid checksums: the content is read

    def gti(rows):
        def change(hl):
            cols = [fits.Column("START", "D", unit="s", array=rows[:, 0]),
                    fits.Column("STOP", "D", unit="s", array=rows[:, 1])]
            hl["GTI"] = fits.BinTableHDU.from_columns(cols, header=hl["GTI"].header, name="GTI")
        return change

    damaged("unsorted.fits", lambda hl: hl["EVENTS"].data["TIME"].__setitem__(
        slice(None), hl["EVENTS"].data["TIME"][::-1].copy()))
    damaged("nan_time.fits", lambda hl: hl["EVENTS"].data["TIME"].__setitem__(3, np.nan))
    damaged("zero_gti.fits", gti(np.array([[0.0, 60.0], [60.0, 60.0], [60.0, 120.0]])))
    damaged("short_gti.fits", gti(np.array([[0.0, 3.0]])))
    raw = (folder / "ev.fits").read_bytes()
    (folder / "trunc.fits").write_bytes(raw[: len(raw) // 3])
    Table({"time": [0.0, 10.0] * u.s, "ra": [120.0, 120.0] * u.deg,
           "dec": [-30.0, -30.0] * u.deg, "roll": [20.0, 20.0] * u.deg}).write(
        folder / "att_10s.ecsv")
    return folder, ev


BURST = ["-e", "300", "--radius", "40", "--no-progress"]


@pytest.mark.parametrize(("events", "extra", "match"), [
    # A bad --interval was "not analysed" and the command exited 0 (after the search).
    ("ev.fits", ["--interval", "60,45"], "--interval: must be two finite times T0,T1"),
    ("ev.fits", ["--interval", "45,45"], "with T1 > T0"),
    ("ev.fits", ["--interval", "nan,45"], "--interval: must be two finite times"),
    ("ev.fits", ["--interval", "inf,inf"], "--interval: must be two finite times"),
    ("ev.fits", ["--interval", "1000,1010"],
     "--interval: 1000,1010 s lies outside the events (0 .. 120 s)"),
    ("ev.fits", ["--interval", "45,60,70"], "--interval: must be T0,T1 (s)"),
    # Refused only after the search, per burst, exit 0.
    ("ev.fits", ["--systematic", "inf"], "argument --systematic: must be finite"),
    ("ev.fits", ["-m", "nope"], "--model"),
    # An attitude table of 10 s analysed a burst at 50 s with its end attitude (exit 0).
    ("ev.fits", ["--attitude", "{f}/att_10s.ecsv"],
     "--attitude: the table covers 0 .. 10 s, but the observation runs 0 .. 120 s"),
    # Held already.
    ("ev.fits", ["--far", "1/0"], "--far: must be a rate in 1/s"),
    ("ev.fits", ["--far", "nan"], "--far: must be > 0 per second"),
    ("ev.fits", ["--far", "1e9"], "far must be < trials_per_second"),
    ("ev.fits", ["--radius", "nan"], "--radius: must be in (0, 90) deg"),
    ("ev.fits", ["--max-step", "-1"], "--max-step: must be > 0 s"),
    ("ev.fits", ["-e", "0"], "--energy: must be > 0 keV"),
    ("ev.fits", ["--pointing", "400,100"], "--pointing: Dec must be in [-90, 90] deg"),
    ("unsorted.fits", [], "events.time must be sorted in increasing order"),
    ("nan_time.fits", [], "events.time must be finite"),
    ("zero_gti.fits", [], "gti intervals must have start < stop, got [60, 60] s (row 1)"),
    ("short_gti.fits", [], "timescales must not be longer than the longest good-time interval"),
    ("trunc.fits", [], "is truncated or corrupt"),
])
def test_burst_command_refuses(burst_events, events, extra, match) -> None:
    f, _ = burst_events
    argv = ["burst", f / events, *BURST, *[str(a).format(f=f) for a in extra], "-o", f / "b"]
    _refused(f, argv, match)


def test_burst_of_no_events_is_a_clear_answer(burst_events) -> None:
    """An empty event list (a band or file with nothing in it) is searched and holds no
    candidate: a true answer, said, exit 0 (decided; docs/reliability.md)."""
    f, _ = burst_events
    before = _snapshot(f)
    code, err = _cli("burst", f / "empty.fits", *BURST, "-o", f / "b")
    assert code == 0 and "0 candidate(s)" in err and "Traceback" not in err
    assert _snapshot(f) == before


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"timescales": [2.0, 1.0]}, "timescales must be increasing"),
    ({"timescales": [np.nan]}, "timescales must be finite"),
    ({"timescales": [1e9]}, "must not be longer than the longest good-time interval"),
    ({"bands": [(300.0, 100.0)]}, "bands[0] must have lo < hi"),
    ({"bands": [(-1.0, 100.0)]}, "bands[0] must be >= 0 keV"),
    ({"far": np.inf}, "far must be finite"),
    ({"far": 1e9}, "far must be < trials_per_second"),
    ({"background_window": 1e9}, "long enough for a window, its gap and its background"),
    ({"gap": -1.0}, "gap must be >= 0 s"),
])
def test_burst_search_refuses(burst_events, kwargs, match) -> None:
    _, ev = burst_events
    with pytest.raises(ParameterError, match=match.replace("[", r"\[").replace("(", r"\(")):
        search(ev, **kwargs)


def test_burst_search_refuses_a_timescale_too_fine(burst_events) -> None:
    # 1e-12 s over 120 s: 4.8e14 fine bins (a quarter of the timescale), refused unmade.
    _, ev = burst_events
    with _within(10), pytest.raises(MemoryBudgetError, match="shortest of timescales"):
        search(ev, timescales=[1e-12])


def test_fit_background_refuses_a_bin_too_fine(burst_events) -> None:
    _, ev = burst_events
    with _within(10), pytest.raises(MemoryBudgetError, match="bin_width"):
        fit_background(ev, [(0.0, 40.0)], bin_width=1e-12)


def test_durations_refuse_endless_bootstrap(burst_events) -> None:
    _, ev = burst_events
    bkg = fit_background(ev, [(0.0, 40.0), (80.0, 120.0)])
    with _within(5), pytest.raises(MemoryBudgetError, match="n_boot"):
        durations(ev, (40.0, 70.0), bkg, n_boot=10**12)  # its values alone: 48 TB


def test_durations_estimate_a_long_bootstrap_from_its_first_chunk(burst_events,
                                                                  monkeypatch) -> None:
    # Within the memory budget but beyond the time budget (1 s here): refused after the
    # first chunk's redraws, with the estimate.
    _, ev = burst_events
    bkg = fit_background(ev, [(0.0, 40.0), (80.0, 120.0)])
    monkeypatch.setenv("ROTMOD_TIME_BUDGET", "1s")
    with _within(10), pytest.raises(TimeBudgetError, match="n_boot = 10000000 bootstrap"):
        durations(ev, (40.0, 70.0), bkg, n_boot=10**7)


# -- OGIP products --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def pha(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("ogip")
    return write_ogip(ogip_spectrum(), folder / "src.pha")


def _edited(pha: Path, folder: Path, name: str, kind: str, change) -> Path:
    """A copy of ``pha`` and its RMF and ARF in ``folder`` with ``change(hdulist)`` applied
    to its ``kind`` file (``pha``, ``rmf`` or ``arf``) and valid checksums."""
    src = ogip_paths(pha)
    out = ogip_paths(folder / f"{name}.pha")
    for key in ("pha", "rmf", "arf"):
        with fits.open(src[key]) as hl:
            hl.readall()
            if key == "pha":
                h = hl["SPECTRUM"].header
                h["RESPFILE"], h["ANCRFILE"], h["BACKFILE"] = (
                    out["rmf"].name, out["arf"].name, "none")
            if key == kind:
                change(hl)
            hl.writeto(out[key], checksum=True)
    return out["pha"]


def _column(name: str, fmt: str, values):
    def change(hl):
        s = hl["SPECTRUM"]
        cols = [c if c.name != name else fits.Column(name, fmt, array=values) for c in s.columns]
        hl["SPECTRUM"] = fits.BinTableHDU.from_columns(cols, header=s.header, name="SPECTRUM")
    return change


def _card(ext: str, key: str, value=None, *, drop: bool = False):
    def change(hl):
        if drop:
            del hl[ext].header[key]
        else:
            hl[ext].header[key] = value
    return change


def _rows(ext: str, n: int):
    def change(hl):
        hl[ext] = fits.BinTableHDU(hl[ext].data[:n], header=hl[ext].header, name=ext)
    return change


def _without(ext: str, column: str):
    def change(hl):
        cols = [c for c in hl[ext].columns if c.name != column]
        hl[ext] = fits.BinTableHDU.from_columns(cols, header=hl[ext].header, name=ext)
    return change


N = 48  # channels of ogip_spectrum
OGIP_CASES = {
    # Tracebacks before (TypeError, ValueError, KeyError, IndexError, MemoryError):
    "COUNTS strings": ("pha", _column("COUNTS", "5A", np.array(["abc"] * N)),
                       "SPECTRUM column COUNTS must hold one number per row"),
    "COUNTS logical": ("pha", _column("COUNTS", "L", np.ones(N, bool)),
                       "SPECTRUM column COUNTS must hold one number per row"),
    "EXPOSURE text": ("pha", _card("SPECTRUM", "EXPOSURE", "abc"),
                      "EXPOSURE must be a number, got 'abc'"),
    "BACKSCAL text": ("pha", _column("BACKSCAL", "3A", np.array(["a"] * N)),
                      "SPECTRUM column BACKSCAL must hold one number per row"),
    "POISSERR text": ("pha", _card("SPECTRUM", "POISSERR", "maybe"),
                      "POISSERR must be T or F, got 'maybe'"),
    "no channels": ("pha", _rows("SPECTRUM", 0), "the SPECTRUM has no channels"),
    "DETCHANS text": ("rmf", _card("MATRIX", "DETCHANS", "x"), "DETCHANS must be a number"),
    "DETCHANS 1e12": ("rmf", _card("MATRIX", "DETCHANS", 10**12),
                      "DETCHANS = 1e+12 but EBOUNDS has 48 channels"),
    "no F_CHAN": ("rmf", _without("MATRIX", "F_CHAN"), "the MATRIX extension has no F_CHAN"),
    "N_GRP 5": ("rmf", lambda hl: hl["MATRIX"].data["N_GRP"].__setitem__(0, 5),
                "row 0 has N_GRP = 5 but 1 groups"),
    "RMF without rows": ("rmf", _rows("MATRIX", 0), "extensions must have rows"),
    "ARF without SPECRESP": ("arf", lambda hl: setattr(hl[1], "name", "OTHER"),
                             "has no SPECRESP extension"),
    "ARF without its column": ("arf", _without("SPECRESP", "SPECRESP"),
                               "the SPECRESP extension has no SPECRESP column"),
    # Refused before, without the file's name:
    "COUNTS 2.5": ("pha", _column("COUNTS", "D", np.full(N, 2.5)),
                   "SPECTRUM column COUNTS must hold integers"),
    "COUNTS negative": ("pha", _column("COUNTS", "J", np.full(N, -3)),
                        "counts must be non-negative integers"),
    "EXPOSURE 0": ("pha", _card("SPECTRUM", "EXPOSURE", 0.0), "exposure must be > 0"),
    "fewer channels than the RMF": ("pha", _rows("SPECTRUM", 10),
                                    "response has 48 channels, counts 10"),
    "MATRIX NaN": ("rmf", lambda hl: hl["MATRIX"].data["MATRIX"][0].__setitem__(
        slice(None), np.nan), "matrix must be finite"),
    "ARF negative": ("arf", lambda hl: hl["SPECRESP"].data["SPECRESP"].__setitem__(
        slice(None), -1.0), "area must be"),
    # Held already.
    "no EXPOSURE": ("pha", _card("SPECTRUM", "EXPOSURE", drop=True), "has no EXPOSURE"),
    "POISSERR F without STAT_ERR": ("pha", _card("SPECTRUM", "POISSERR", False),
                                    "POISSERR = F needs errors > 0 in STAT_ERR"),
    "no EBOUNDS": ("rmf", lambda hl: hl.__delitem__("EBOUNDS"), "not an OGIP RMF"),
}


@pytest.mark.parametrize("case", sorted(OGIP_CASES))
def test_ogip_files_refused_naming_the_file(pha, tmp_path, case) -> None:
    kind, change, match = OGIP_CASES[case]
    path = _edited(pha, tmp_path, case.replace(" ", "_"), kind, change)
    before = _snapshot(tmp_path)
    with pytest.raises(RotmodError) as info:
        read_ogip(path)
    message = str(info.value)
    assert match in message, message
    assert f"file '{tmp_path}/" in message  # the file that holds the mistake
    assert _snapshot(tmp_path) == before


def test_ogip_counts_read_as_whole_numbers(pha, tmp_path) -> None:
    """A float COUNTS column holding whole numbers (as some tools write it) reads exactly."""
    counts = np.arange(N, dtype=float)
    path = _edited(pha, tmp_path, "float", "pha", _column("COUNTS", "D", counts))
    np.testing.assert_array_equal(read_ogip(path).counts, counts.astype(int))


def test_ogip_writer_refuses_before_writing(pha, tmp_path) -> None:
    spec = ogip_spectrum()
    # Counts above 2^31 were written as 32-bit COUNTS wrapped to 0 (read back as 0: data lost).
    big = CountsSpectrum(np.full(N, 2**33), 1e4, spec.response)
    with pytest.raises(ParameterError, match="counts must be at most 2147483647 per channel"):
        write_ogip(big, tmp_path / "big.pha")
    # A missing folder and a folder in the way were the operating system's errors at the end;
    # the folder case after the RMF and ARF had appeared (not "all four or none").
    with pytest.raises(ParameterError, match=r"folder '.*nope' does not exist"):
        write_ogip(spec, tmp_path / "nope" / "s.pha")
    (tmp_path / "d.pha").mkdir()
    with pytest.raises(ParameterError, match=r"d\.pha' is a folder; give a file name"):
        write_ogip(spec, tmp_path / "d.pha", overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.pha"]
    raw = pha.read_bytes()
    with pytest.raises(ParameterError, match="already exists"):
        write_ogip(spec, pha)
    assert pha.read_bytes() == raw


@pytest.mark.parametrize(("make", "reason"), [
    (lambda r: CountsSpectrum(np.array(["a"] * N), 1.0, r), "strings: TypeError from isfinite"),
    (lambda r: CountsSpectrum(np.full(N, 1e20), 1.0, r),
     "1e20 counts cast silently to -9.2e18 (int64 overflow)"),
    (lambda r: CountsSpectrum(np.ones(N, int), 1.0, "rmf"), "response 'rmf': AttributeError"),
    (lambda r: CountsSpectrum(np.ones(N, int), 1.0, r, background="b"),
     "background 'b': AttributeError"),
])
def test_counts_spectrum_refuses(make, reason) -> None:
    response = ogip_spectrum().response
    with pytest.raises(ParameterError):
        make(response)


# -- spectral models ------------------------------------------------------------------------


@pytest.mark.parametrize(("make", "match"), [
    (lambda: Band(alpha=-2.5), "Band.alpha must be > -2"),
    (lambda: Band(alpha=-1.0, beta=0.0), "Band.beta must be < Band.alpha"),
    (lambda: Band(alpha=-1.0, beta=-1.0), "Band.beta must be < Band.alpha"),
    (lambda: Band(xp=0.0), "Band.xp must be > 0"),
    (lambda: Band(xp=-100.0), "Band.xp must be > 0"),
    (lambda: Band(xp=np.inf), "Band.xp must be finite"),
    (lambda: Band().with_parameters(beta=0.0), "Band.beta must be < Band.alpha"),
    (lambda: CutoffPowerLaw(xc=0.0), "CutoffPowerLaw.xc must be > 0"),
    (lambda: PowerLaw(K=-1.0), "PowerLaw.K must be > 0"),
    (lambda: PowerLaw(index=np.nan), "PowerLaw.index must be finite"),
    (lambda: PowerLaw(index="a"), "PowerLaw.index must be numeric"),
    (lambda: PowerLaw(K=1 * u.m), "PowerLaw.K must be a plain number"),
    (lambda: PowerLaw().with_parameters(foo=1.0), "PowerLaw has no parameter 'foo'"),
    (lambda: PowerLaw()(-1.0), "energy must be > 0 keV, got -1 keV"),
    (lambda: PowerLaw()(1 * u.m), "energy must be in units of keV"),
    (lambda: PowerLaw().integral([2.0], [1.0]), "energy bins must satisfy 0 < e_lo < e_hi"),
    (lambda: PowerLaw().integral([1.0, 2.0], [3.0]), "e_lo and e_hi must have one shape"),
    (lambda: Band().integral([-2.0], [1.0]), "e_lo must be > 0 keV"),
    (lambda: PowerLaw().node_weights([3.0, 2.0, 1.0]), "nodes must be two or more increasing"),
    (lambda: photons.PowerLaw(2.0, 0.0, 100.0), "spectrum.e_min must be > 0 keV"),
    (lambda: photons.PowerLaw(2.0, 100.0, 10.0), "spectrum.e_min must be < e_max"),
    (lambda: photons.PowerLaw(2.0, 10.0, np.inf), "spectrum.e_max must be finite"),
    (lambda: photons.PowerLaw(2.0, 10.0, 100.0).bands(2.5), "n_bands must be an integer"),
    (lambda: photons.EnergyResolution(0.0), "resolution.fraction must be > 0"),
    (lambda: photons.EnergyResolution(0.07, -1.0), "resolution.reference must be > 0 keV"),
    # Fixed here (rotmod/energy.py): a MemoryError, a FWHM of inf, values outside [lo, hi],
    # an AttributeError.
    (lambda: photons.PowerLaw(2.0, 10.0, 100.0).bands(10**12), "10^12 energy bands"),
    (lambda: photons.EnergyResolution(0.07, 662.0, 1000.0).fwhm(1e4),
     "resolution: the FWHM at 10000 keV is not finite"),
    (lambda: photons.PowerLaw(2.0, 10.0, 100.0).draw(100.0, 10.0, np.random.default_rng(0)),
     "lo must be <= hi"),
    (lambda: photons.PowerLaw(2.0, 10.0, 100.0).draw(-1.0, 10.0, np.random.default_rng(0)),
     "lo must be > 0 keV"),
    (lambda: photons.EnergyResolution().smear(100.0, None), "rng must be a numpy Generator"),
    (lambda: fit_spectrum(CountsSpectrum(ogip_spectrum().counts, 1e4,
                                         ogip_spectrum().response), PowerLaw(), channels=[100]),
     "channels must select among the 48 channels"),
    (lambda: fit_spectrum(ogip_spectrum(), PowerLaw(), free=["foo"]),
     "free must name parameters of PowerLaw"),
    (lambda: fit_spectrum(ogip_spectrum(), "powerlaw"), "SpectralModel"),
])
def test_spectral_parameters_refused(make, match) -> None:
    with pytest.raises(RotmodError) as info:  # ParameterError, MemoryBudgetError
        make()
    assert match.replace("10^12", "1000000000000") in str(info.value)


@pytest.mark.parametrize("index", [-1000.0, -7.3, -1.0, 0.0, 1.0, 2.0, 3.7, 1000.0])
def test_photon_power_law_fractions_hold_for_any_index(index) -> None:
    """The bands' photon fractions and the drawn energies of ``E^-index`` are finite, sum to
    1 and fall in their bands for any index (an index of +-1000 gave NaN fractions and inf
    energies).  Against the integral of ``E^-index`` by quadrature (scipy, relative 1e-10
    requested; 1e-9 allowed) where that is representable (``|index| < 50``)."""
    spectrum = photons.PowerLaw(index, 10.0, 100.0)
    lo, hi, frac = spectrum.bands(4)
    assert np.all(np.isfinite(frac)) and np.all(frac >= 0)
    assert frac.sum() == pytest.approx(1.0, abs=1e-12)
    if abs(index) < 50:
        parts = [integrate.quad(lambda e: e**-index, a, b, epsrel=1e-10)[0]
                 for a, b in zip(lo, hi, strict=True)]
        np.testing.assert_allclose(frac, np.array(parts) / sum(parts), rtol=1e-9)
    drawn = spectrum.draw(np.repeat(lo, 1000), np.repeat(hi, 1000), np.random.default_rng(5))
    assert np.all(np.isfinite(drawn))
    assert np.all((drawn >= np.repeat(lo, 1000) * (1 - 1e-12))
                  & (drawn <= np.repeat(hi, 1000) * (1 + 1e-12)))


@pytest.mark.parametrize("make", [
    lambda: PowerLaw(1.0, 1000.0)(1e4),
    lambda: PowerLaw(1.0, -1000.0)(1.0),
    lambda: PowerLaw(1.0, -1000.0).integral([1.0], [2.0]),
    lambda: PowerLaw(1e308, -2.0)(1.0),
])
def test_spectral_model_overflow_refused(make) -> None:
    with pytest.raises(ParameterError):
        make()


def test_fit_of_no_counts_refused() -> None:
    spec = ogip_spectrum()
    with pytest.raises(ParameterError):
        fit_spectrum(CountsSpectrum(np.zeros(N, int), 1e4, spec.response),
                     PowerLaw(2e-4, -1.5))


def _columns() -> tuple[SpectralColumns, np.ndarray, np.ndarray]:
    """One source, 5 node energies, 2 detectors, 4 bins, 3 channels (known, random)."""
    rng = np.random.default_rng(0)
    cols = SpectralColumns(rng.uniform(0.5, 1.0, (1, 1, 5, 2, 4)), np.eye(5, 3)[None, None] * 0.9,
                           np.geomspace(50.0, 500.0, 5), np.geomspace(40.0, 600.0, 4),
                           np.array([[5.0]]))
    return cols, rng.poisson(5.0, (2, 4, 3)), np.full(4, 10.0)


@pytest.mark.parametrize(("call", "match"), [
    (lambda c, y, t: fit_spectra(c, y[:, :2], t, [PowerLaw()]), "counts must have shape"),
    (lambda c, y, t: fit_spectra(c, y, np.ones(7), [PowerLaw()]), "exposure must be finite"),
    (lambda c, y, t: fit_spectra(c, y, t, [PowerLaw(), PowerLaw()]),
     "models must give one spectrum per source"),
    (lambda c, y, t: fit_spectra(c, np.full(y.shape, np.nan), t, [PowerLaw()]),
     "counts must be finite and non-negative"),
    (lambda c, y, t: fit_spectra(c, y, t, [PowerLaw()], off_counts=np.ones((3, 3)),
                                 off_exposure=1.0), "off_counts must be non-negative"),
    (lambda c, y, t: extract_spectrum(c, y, t, 5), "source must be the index of one of"),
    (lambda c, y, t: extract_spectrum(c, y, t, 0, subdivide=0), "subdivide must be an integer"),
    (lambda c, y, t: extract_spectrum(c, y, np.zeros(4), 0), "exposure is 0 everywhere"),
])
def test_source_spectra_refuse(call, match) -> None:
    with pytest.raises(ParameterError, match=match):
        call(*_columns())


@pytest.mark.parametrize("call", [
    lambda c, y, t: fit_spectra(c, y, np.zeros(4), [PowerLaw()]),
    lambda c, y, t: fit_spectra(c, y, t, PowerLaw()),
    lambda c, y, t: extract_spectrum(c, y, t, 0, subdivide=10**12),
])
def test_source_spectra_refuse_still(call) -> None:
    # A size beyond the memory budget is refused as such (MemoryBudgetError, with the
    # estimate), a bad value as a ParameterError.
    with _within(10), pytest.raises((ParameterError, MemoryBudgetError)):
        call(*_columns())
