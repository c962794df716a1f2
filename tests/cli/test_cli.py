"""The rotmod command line, called in-process: help, every subcommand, chain, exit codes."""

from __future__ import annotations

import numpy as np
import pytest

from rotmod.cli import main


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize(
    "cmd", ["", "profile", "simulate", "fold", "response", "reconstruct", "detect", "lightcurve",
            "design", "reproduce"]
)
def test_help(capsys, cmd: str) -> None:
    code, out, _ = run(capsys, *([cmd] if cmd else []), "--help")
    assert code == 0
    assert "usage: rotmod" in out


def _option_help(command: str, option: str) -> str:
    import argparse

    from rotmod.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return next(a.help for a in sub.choices[command]._actions if option in a.option_strings)


def test_help_lists_the_registries() -> None:
    # The names come from the registries, so a newly registered model or method shows up.
    from rotmod.paper.report import STEPS
    from rotmod.profiles import MODELS
    from rotmod.reconstruction import ALGORITHMS
    from rotmod.reconstruction.api import DEFAULT_METHOD

    for command in ("profile", "response", "detect", "lightcurve"):
        assert ", ".join(MODELS.names()) in _option_help(command, "--model")
    assert ", ".join(ALGORITHMS.names()) in _option_help("reconstruct", "--method")
    assert f"default {DEFAULT_METHOD}" in _option_help("reconstruct", "--method")
    assert ", ".join(STEPS) in _option_help("reproduce", "--steps")


def test_unknown_names_suggest_the_closest(capsys, tmp_path) -> None:
    code, _, err = run(capsys, "profile", "-s", "1,1", "-m", "advancd", "-o", tmp_path / "x.csv")
    assert code == 2 and "--model: must be one of" in err and "did you mean 'advanced'?" in err
    assert not (tmp_path / "x.csv").exists()


def test_no_command_is_a_usage_error(capsys) -> None:
    code, _, err = run(capsys)
    assert code == 2 and "usage" in err


def test_profile_table_and_plot(capsys, tmp_path) -> None:
    from astropy.table import Table

    out, png = tmp_path / "p.ecsv", tmp_path / "p.png"
    code, _, err = run(capsys, "profile", "-i", "paper", "-s", "6,30", "-s", "48,0",
                       "--angles", "36", "-o", out, "--plot", png)
    assert code == 0, err
    t = Table.read(out)
    assert set(t["model"]) == {"standard", "advanced", "exact"}
    assert len(t) == 3 * 2 * 36
    assert np.all((t["profile"] >= 0) & (t["profile"] <= 1))
    assert png.stat().st_size > 0
    # An explicitly requested model outside its validity is a user error.
    code, _, err = run(capsys, "profile", "-i", "paper", "-s", "80,0", "-m", "advanced",
                       "--energy", "662", "-o", tmp_path / "x.csv")
    assert code == 2 and err.startswith("rotmod: error: ") and "Traceback" not in err


def test_chain_simulate_fold_response_reconstruct(capsys, tmp_path) -> None:
    from rotmod.io import read_events, read_folded
    from rotmod.io.images import read_image

    inst = tmp_path / "inst.toml"
    inst.write_text(
        'rotation_period = "10 s"\nenergies = ["122 keV"]\n'
        '[mask]\nslat_width = "4 cm"\nslat_gap = "4 cm"\nthickness = "1 cm"\n'
        'height = "100 cm"\n[material]\nname = "lead"\n'
        '[detectors]\nlayout = "hexagonal"\ndiameter = "4 cm"\nrings = 1\n'
    )
    ev, fo, rs, im = (tmp_path / n for n in ("ev.fits", "fo.fits", "r.zarr", "im.fits"))
    code, _, err = run(capsys, "simulate", "-i", inst, "-s", "2.5,30,40", "-t", "100",
                       "--seed", "1", "-o", ev, "--no-progress")
    assert code == 0, err
    assert len(read_events(ev)) > 1000
    code, _, err = run(capsys, "fold", ev, "-n", "36", "-o", fo)
    assert code == 0, err
    assert read_folded(fo).counts.shape == (7, 36)
    code, _, err = run(capsys, "response", "-i", inst, "-m", "exact", "--fov", "8",
                       "--pixel", "1", "-n", "36", "-o", rs, "--no-progress")
    assert code == 0, err
    code, _, err = run(capsys, "reconstruct", fo, rs, "--method", "mlem", "--max-iter", "30",
                       "-o", im, "--plot", tmp_path / "im.png", "--mark", "2.5,30")
    assert code == 0, err
    img = read_image(im)
    assert img.image.shape == (8, 8)
    # Each product says how it was made: the command line, and the seed where one was used.
    from astropy.io import fits

    with fits.open(ev) as e, fits.open(fo) as f, fits.open(im) as i:
        assert e[0].header["SEED"] == 1 and e[0].header["COMMAND"].startswith("rotmod simulate")
        assert f[0].header["COMMAND"].startswith("rotmod fold") and "SEED" not in f[0].header
        assert i[0].header["SEED"] == 0 and "mlem" in i[0].header["COMMAND"]
    # A fresh seed is recorded too, so that any run can be repeated.
    ev3 = tmp_path / "ev3.fits"
    assert run(capsys, "simulate", "-i", inst, "-s", "2.5,30,40", "-t", "5", "-o", ev3,
               "--no-progress")[0] == 0
    with fits.open(ev3) as e:
        fresh = int(e[0].header["SEED"])
    again = tmp_path / "again.fits"
    assert run(capsys, "simulate", "-i", inst, "-s", "2.5,30,40", "-t", "5", "--seed",
               str(fresh), "-o", again, "--no-progress")[0] == 0
    np.testing.assert_array_equal(read_events(again).time, read_events(ev3).time)
    iy, ix = np.unravel_index(np.argmax(img.image), img.image.shape)
    # Source at tangent (2.16, 1.25) deg: pixel centres are at -3.5 .. 3.5 in 1 deg steps.
    assert (ix, iy) == (6, 5)
    # Mismatched binning is a user error, not a traceback.
    fo2 = tmp_path / "fo2.fits"
    assert run(capsys, "fold", ev, "-n", "20", "-o", fo2)[0] == 0
    code, _, err = run(capsys, "reconstruct", fo2, rs, "-o", tmp_path / "im2.fits")
    assert code == 2 and "time bins" in err and "Traceback" not in err
    # An existing output is refused without --overwrite.
    code, _, err = run(capsys, "reconstruct", fo, rs, "-o", im)
    assert code == 2 and "exists" in err
    # A response computed for another instrument is refused.
    rs2 = tmp_path / "paper.zarr"
    assert run(capsys, "response", "-i", "paper", "--fov", "4", "--pixel", "2", "-n", "36",
               "-o", rs2, "--no-progress")[0] == 0
    code, _, err = run(capsys, "reconstruct", fo, rs2, "-o", tmp_path / "im3.fits")
    assert code == 2 and "does not match" in err and "Traceback" not in err
    # The same image from a stored Radon table (the exact model within 1e-4).
    rr, im4 = tmp_path / "radon.zarr", tmp_path / "im4.fits"
    code, _, err = run(capsys, "response", "-i", inst, "--operator", "radon", "--fov", "8",
                       "--pixel", "1", "-n", "36", "-o", rr)
    assert code == 0 and "Radon table" in err, err
    code, _, err = run(capsys, "reconstruct", fo, rr, "--method", "mlem", "--max-iter", "30",
                       "-o", im4)
    assert code == 0, err
    img4 = read_image(im4).image
    assert np.unravel_index(np.argmax(img4), img4.shape) == (5, 6)
    code, _, err = run(capsys, "response", "-i", inst, "--operator", "radon", "-m", "standard",
                       "-o", tmp_path / "x.zarr")
    assert code == 2 and "factorises the exact model" in err
    code, _, err = run(capsys, "response", "-i", inst, "--operator", "radon", "--tolerance",
                       "0", "-o", tmp_path / "y.zarr")
    assert code == 2 and "tolerance must be > 0" in err and "Traceback" not in err


def test_design_writes_table_and_plot(capsys, tmp_path) -> None:
    from astropy.table import Table

    code, out, err = run(capsys, "design", "-i", "paper", "--a", "2:6:3", "--b", "2,4",
                         "--energies", "662", "--angles", "16", "--rings", "2",
                         "--azimuths", "2", "-o", tmp_path / "d.csv", "--plot",
                         tmp_path / "d.png", "--no-progress")
    assert code == 0, err
    assert "Pareto front" in out and "best for weights" in out
    t = Table.read(tmp_path / "d.csv", format="ascii.csv")
    assert len(t) == 6 and "pareto" in t.colnames
    assert (tmp_path / "d.png").exists()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["profile", "-i", "nosuchpreset", "-s", "1,1", "-o", "{tmp}/x.csv"],
         "neither an existing file nor a preset"),
        (["profile", "-i", "{tmp}/bad.toml", "-s", "1,1", "-o", "{tmp}/x.csv"],
         r"mask.slat_width: must be >= 0 cm, got -4 cm"),
        (["fold", "{tmp}/missing.fits", "-o", "{tmp}/f.fits"], "does not exist"),
        (["fold", "{tmp}/garbage.fits", "-o", "{tmp}/f.fits"], ""),
        (["profile", "-i", "paper", "-s", "1,1", "-o", "{tmp}/nodir/x.csv"], "does not exist"),
        (["simulate", "-i", "paper", "-s", "1,1", "-t", "-5", "-o", "{tmp}/e.fits"],
         "--exposure: must be > 0 s"),
        (["response", "-i", "paper", "-m", "magic", "-o", "{tmp}/r.zarr"], "--model: must be"),
    ],
)
def test_user_errors_exit_2_with_one_line(capsys, tmp_path, argv, message) -> None:
    (tmp_path / "bad.toml").write_text(
        '[mask]\nslat_width = "-4 cm"\nslat_gap = "4 cm"\nthickness = "1 cm"\n'
        'height = "1 m"\n[detectors]\ndiameter = "4 cm"\n'
    )
    (tmp_path / "garbage.fits").write_text("not a fits file")
    code, _, err = run(capsys, *[a.format(tmp=tmp_path) for a in argv])
    assert code == 2
    assert err.startswith("rotmod: error: ") and "Traceback" not in err
    assert message in err


def test_usage_errors_exit_2(capsys, tmp_path) -> None:
    code, _, err = run(capsys, "profile", "-s", "95,0", "-o", tmp_path / "x.csv")
    assert code == 2 and "zenith must be in [0, 90)" in err
    code, _, err = run(capsys, "design", "--weights", "1,2", "-o", tmp_path / "x.csv")
    assert code == 2 and "--weights" in err


def test_unexpected_errors_exit_1(capsys, monkeypatch, tmp_path) -> None:
    import rotmod.design

    def boom(**kw):
        raise RuntimeError("kaboom")

    monkeypatch.setattr(rotmod.design, "scan_designs", boom)
    code, _, err = run(capsys, "design", "-o", tmp_path / "d.csv")
    assert code == 1 and "kaboom" in err and "bug" in err
