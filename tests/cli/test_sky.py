"""The command line on the real sky: attitude file -> simulate -> fold -> response on a
celestial and a HEALPix grid -> reconstruct, the source found at its RA/Dec; the defaults
that chain; the mirror-source warning; progress off a terminal; a fast top-level parser."""

from __future__ import annotations

import logging
import subprocess
import sys
import time

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import ICRS, SkyCoord
from astropy.io import fits
from astropy.table import Table

from rotmod.cli import build_parser, main
from rotmod.io import read_events
from rotmod.io.images import read_image
from rotmod.progress import Progress
from rotmod.sky import AttitudeTable

#: The true source (ICRS, deg), 0.8 deg from the mid-observation pointing.
SOURCE = SkyCoord(201.0 * u.deg, -59.5 * u.deg)


def run(capsys, *argv: object) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _brightest(path) -> SkyCoord:
    """The sky position of the brightest pixel, from the file alone: its celestial WCS, or
    its HEALPix table (PIX, VALUE, NSIDE, ORDERING) read as healpy and gammapy do."""
    img = read_image(path)
    if img.wcs is not None:
        iy, ix = np.unravel_index(int(np.argmax(img.image)), img.image.shape)
        return img.wcs.celestial.pixel_to_world(ix, iy)
    hp = pytest.importorskip("astropy_healpix")
    with fits.open(path) as hdus:
        h, t = hdus["HEALPIX"].header, Table.read(hdus["HEALPIX"])
    grid = hp.HEALPix(nside=h["NSIDE"], order=h["ORDERING"].lower(), frame=ICRS())
    return grid.healpix_to_skycoord(int(t["PIX"][int(np.argmax(t["VALUE"]))]))


def test_sky_chain_finds_the_source_at_its_ra_dec(capsys, tmp_path) -> None:
    # A 10-minute drift of 0.8 deg in RA, 0.4 deg in Dec and 20 deg of roll, in 6 pieces.
    aspect = tmp_path / "aspect.ecsv"
    table = AttitudeTable([0, 300, 600], [200.0, 200.4, 200.8], [-60.0, -60.2, -60.4],
                          [10.0, 20.0, 30.0])
    table.write(aspect)
    ev, fo = tmp_path / "ev.fits", tmp_path / "fo.fits"
    drift = ("--attitude", aspect, "--max-step", "100")
    code, _, err = run(capsys, "simulate", "-i", "prototype", *drift, "--sky-source",
                       f"{SOURCE.ra.deg},{SOURCE.dec.deg},40", "-t", "600", "--seed", "1",
                       "-o", ev)
    assert code == 0 and "6 attitude pieces" in err, err
    # The file records the pointing of the middle piece (300-400 s: the attitude at 350 s).
    att, mid = read_events(ev).attitude, table.at(350.0)
    assert att is not None
    assert (att.ra, att.dec, att.roll) == pytest.approx((mid.ra, mid.dec, mid.roll), abs=1e-6)
    assert run(capsys, "fold", ev, "-n", "90", "-o", fo)[0] == 0

    # A 12 x 12 TAN image of 0.5 deg pixels around the mid pointing.
    rs, im = tmp_path / "sky.zarr", tmp_path / "sky.fits"
    code, _, err = run(capsys, "response", "-i", "prototype", "--grid", "celestial", *drift,
                       "--fov", "6", "--pixel", "0.5", "-m", "exact", "-n", "90", "-o", rs)
    assert code == 0 and "celestial grid 12x12" in err, err
    code, _, err = run(capsys, "reconstruct", fo, rs, "-o", im, "--plot", tmp_path / "s.png",
                       "--mark-sky", f"{SOURCE.ra.deg},{SOURCE.dec.deg}")
    assert code == 0 and "brightest pixel at RA " in err, err
    # 2e5 events of one bright source: the brightest pixel is the one that holds the source,
    # so its centre is at most half a pixel diagonal away (0.5 deg * sqrt(2) / 2 = 0.354).
    assert _brightest(im).separation(SOURCE).deg < 0.5 * np.sqrt(2) / 2

    # The same data on HEALPix nside 128 (pixels 58.6/128 = 0.46 deg across) within 3 deg.
    rh, ih = tmp_path / "hpx.zarr", tmp_path / "hpx.fits"
    code, _, err = run(capsys, "response", "-i", "prototype", "--grid", "healpix", *drift,
                       "--nside", "128", "--radius", "3", "-m", "exact", "-n", "90", "-o", rh)
    assert code == 0 and "healpix grid" in err, err
    assert run(capsys, "reconstruct", fo, rh, "-o", ih)[0] == 0
    # HEALPix pixels are not squares: the source's own pixel has its centre within one
    # pixel size (0.46 deg) of it.
    assert _brightest(ih).separation(SOURCE).deg < 58.6 / 128


def test_fixed_pointing_and_instrument_sources(capsys, tmp_path) -> None:
    ev = tmp_path / "ev.fits"
    code, _, err = run(capsys, "simulate", "-i", "prototype", "--pointing", "83.6,22.0",
                       "--roll", "30", "--sky-source", "84.5,23.0,20", "--source", "3,40,5",
                       "-t", "20", "--seed", "2", "-o", ev)
    assert code == 0 and "pointing RA 83.6 Dec 22 deg" in err, err
    events = read_events(ev)
    assert (events.attitude.ra, events.attitude.roll) == pytest.approx((83.6, 30.0))
    assert set(np.unique(events.source)) == {0, 1}
    # Sky sources need an attitude; an attitude table needs sky sources.
    code, _, err = run(capsys, "simulate", "-i", "prototype", "--sky-source", "84,23", "-t",
                       "1", "-o", tmp_path / "x.fits")
    assert code == 2 and "--sky-source: needs the attitude" in err
    code, _, err = run(capsys, "response", "-i", "prototype", "--grid", "celestial", "-o",
                       tmp_path / "x.zarr")
    assert code == 2 and "--grid celestial: needs the attitude" in err
    code, _, err = run(capsys, "simulate", "-i", "prototype", "--pointing", "10,95",
                       "--sky-source", "10,80", "-t", "1", "-o", tmp_path / "y.fits")
    assert code == 2 and "--pointing: Dec must be in [-90, 90] deg, got 95" in err


def _default(command: str, option: str) -> object:
    import argparse

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return next(a.default for a in sub.choices[command]._actions if option in a.option_strings)


def test_fold_and_response_defaults_chain() -> None:
    assert _default("fold", "--bins") == _default("response", "--bins") == 360


def test_reconstruct_checks_bins_before_reading_the_response(capsys, tmp_path) -> None:
    ev, fo, rs = tmp_path / "ev.fits", tmp_path / "fo.fits", tmp_path / "r.zarr"
    assert run(capsys, "simulate", "-i", "prototype", "-s", "2,30,20", "-t", "10", "--seed",
               "1", "-o", ev)[0] == 0
    assert run(capsys, "fold", ev, "-n", "20", "-o", fo)[0] == 0
    assert run(capsys, "response", "-i", "prototype", "--fov", "4", "--pixel", "2", "-n", "36",
               "-o", rs)[0] == 0
    # Remove the response's values: only its metadata is read before the bins are refused.
    data = [p for p in rs.rglob("*") if p.is_file() and "zarr.json" not in p.name]
    assert data
    for p in data:
        p.unlink()
    code, _, err = run(capsys, "reconstruct", fo, rs, "-o", tmp_path / "im.fits")
    assert code == 2 and "has 36 time bins" in err and "has 20" in err, err


def test_single_axis_detector_warns_of_the_mirror(capsys, tmp_path) -> None:
    code, _, err = run(capsys, "simulate", "-i", "paper", "-s", "6,30,5", "-t", "2",
                       "--seed", "1", "-o", tmp_path / "ev.fits")
    assert code == 0
    assert "WARNING: rotmod simulate: all 1 detector(s)" in err and "phi + 180 deg" in err
    # The prototype's 19 detectors (point-symmetric, but off the axis) do not warn.
    code, _, err = run(capsys, "simulate", "-i", "prototype", "-s", "6,30,5", "-t", "2",
                       "--seed", "1", "-o", tmp_path / "ev2.fits")
    assert code == 0 and "WARNING" not in err


def test_help_examples_use_an_array_and_list_the_presets(capsys) -> None:
    from rotmod.io import list_presets

    for cmd in ("profile", "simulate", "fold", "response", "reconstruct", "design"):
        code, out, _ = run(capsys, cmd, "--help")
        assert code == 0 and "-i paper" not in out
        if cmd not in ("fold", "reconstruct"):
            assert "-i prototype" in out.replace("\n", " ")
            assert ", ".join(list_presets()) in " ".join(out.split())


def test_progress_logs_lines_off_a_terminal(caplog) -> None:
    with caplog.at_level(logging.INFO, logger="rotmod"), \
            Progress(10, "work", "step", interval=0.05, tty=False) as bar:
        bar.update_to(4, 10)
        for _ in range(100):  # the beat comes from a thread, without any update
            if any("work: 4/10 step (40%)" in r.getMessage() for r in caplog.records):
                break
            time.sleep(0.02)
    assert any("work: 4/10 step (40%)" in r.getMessage() for r in caplog.records)


def test_top_level_help_imports_no_science() -> None:
    code = ("import sys; from rotmod.cli import main; main(['--help']); "
            "print(sorted(m for m in sys.modules if m.startswith(('rotmod.cli.', "
            "'rotmod.response', 'rotmod.io', 'rotmod.sky', 'rotmod.geometry', "
            "'rotmod.profiles', 'matplotlib', 'numba', 'astropy'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"


def test_the_mirror_rule_behind_the_warning() -> None:
    """The half turn about the axis maps the mask to itself, a source at (theta, phi) to
    (theta, phi + 180) and a detector at r to -r: an axis detector sees both alike; the
    prototype's point-symmetric array sees the mirror with its detectors swapped."""
    from rotmod.cli._common import mirror_degenerate
    from rotmod.io import load_instrument
    from rotmod.profiles import get_model

    xi = np.arange(0.0, 360.0, 4.0)
    for name, degenerate in (("paper", True), ("prototype", False)):
        inst = load_instrument(name)
        assert mirror_degenerate(inst) is degenerate
        p = get_model("exact").profile(inst, [6.0, 6.0], [30.0, 210.0], xi, 122.0)
        pos = np.asarray(inst.detectors.positions, dtype=float)
        partner = [int(np.argmin(np.hypot(*(pos + r).T))) for r in pos]  # the one at -r
        np.testing.assert_allclose(p[:, :, 0], p[partner, :, 1], atol=1e-12)
        assert bool(np.abs(p[:, :, 0] - p[:, :, 1]).max() < 1e-12) is degenerate


def test_marks_the_plot_cannot_draw_and_uncovered_attitudes_are_refused_up_front() -> None:
    from rotmod.cli._common import UserError, intervals_of
    from rotmod.cli._reconstruct import _check_marks

    sky, frame = SkyCoord([84.5] * u.deg, [23.0] * u.deg), (np.array([1.0]), np.array([30.0]))
    _check_marks(sky, "celestial")
    _check_marks(frame, "instrument")
    _check_marks(None, "healpix")
    with pytest.raises(UserError, match=r"--mark-sky: .* grid is 'instrument'; use --mark"):
        _check_marks(sky, "instrument")
    with pytest.raises(UserError, match=r"--mark-sky: .* grid is 'healpix'"):
        _check_marks(sky, "healpix")
    with pytest.raises(UserError, match=r"--mark: .* grid is 'celestial'; use --mark-sky"):
        _check_marks(frame, "celestial")
    # Outside its samples a table would hold its end attitude: a silently frozen drift.
    table = AttitudeTable([0.0, 200.0], [83.0, 84.0], [22.0, 22.5], [0.0, 10.0])
    assert len(intervals_of(table, 0.0, 200.0, 50.0)) == 4
    with pytest.raises(UserError, match=r"--attitude: the table covers 0 \.\. 200 s, but the "
                                        r"observation runs 0 \.\. 600 s"):
        intervals_of(table, 0.0, 600.0, 50.0)
    # The table's own test (AttitudeTable.covers) decides: round-off past the end (1e-7 s,
    # a time through a double MJD) is covered, 1e-5 s is not (tolerance 1 us here).
    assert intervals_of(table, 0.0, 200.0 + 1e-7, 50.0)[-1][1] == 200.0 + 1e-7
    with pytest.raises(UserError, match=r"--attitude: the table covers 0 \.\. 200 s"):
        intervals_of(table, 0.0, 200.0 + 1e-5, 50.0)
