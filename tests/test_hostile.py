"""Hostile input: every mistake gets a one-line error naming what was wrong, no traceback,
and nothing a user owns is destroyed (issue 13's examples that rotmod now refuses)."""

from __future__ import annotations

import re
import shutil
from types import SimpleNamespace

import numpy as np
import pytest
from astropy.io import fits

from rotmod import Instrument, get_model
from rotmod.cli import main
from rotmod.errors import ParameterError, RotmodError
from rotmod.events import FoldedProfiles, fold
from rotmod.io import read_folded, write_events, write_folded
from rotmod.materials import PAPER_SIGMA_662
from rotmod.montecarlo import simulate_observation
from rotmod.reconstruction import reconstruct
from rotmod.response import TimeBinning, build_response, write_response
from rotmod.sky import PointSources, SkyGrid


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("hostile")
    inst = Instrument.paper()
    ev = simulate_observation(inst, PointSources([3.0], [20.0], rate=20.0, energy=122.0),
                              t_stop=120.0, seed=4)
    write_events(ev, d / "ev.fits")
    write_folded(fold(ev, 12), d / "f.fits")
    write_response(d / "r.zarr", inst, SkyGrid((3, 3), 1.0), 12, energy=122, progress=False)
    return d


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    return code, err


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["profile", "-s", "6,0", "--mc-photons", "-1", "-o", "{d}/p.csv"],
         "--mc-photons: must be an integer >= 0, got '-1'"),
        (["profile", "-s", "6,0", "--angles", "2.5", "-o", "{d}/p.csv"],
         "--angles: must be an integer >= 1"),
        (["profile", "-s", "6,0", "-o", "{d}/p.csv", "--plot", "{d}/p.txt"],
         "--plot '{d}/p.txt': the extension must be an image format"),
        (["fold", "{d}/ev.fits", "-o", "{d}/ev.fits", "--overwrite"],
         "is also an input of this command"),
        (["fold", "{d}/ev.fits", "-o", "{d}/f2.fits", "-n", "0"],
         "--bins: must be an integer >= 1"),
        (["reconstruct", "{d}/f.fits", "{d}/r.zarr", "-o", "{d}/f.fits", "--overwrite"],
         "is also an input of this command"),
        (["reconstruct", "{d}/f.fits", "{d}/r.zarr", "-o", "{d}/i.fits", "--mark", "95,0"],
         "zenith must be in \\[0, 90\\) deg"),
    ],
)
def test_cli_mistakes_are_one_line_errors(capsys, files, argv, match) -> None:
    before = (files / "ev.fits").read_bytes()
    code, err = _cli(capsys, *(a.format(d=files) for a in argv))
    assert code == 2, err
    # argparse prints its usage first; the error itself is one line, and no traceback.
    assert "Traceback" not in err
    assert re.search(match.format(d=files), err.strip().splitlines()[-1]), err
    assert (files / "ev.fits").read_bytes() == before  # the input is never touched
    assert not (files / "p.csv").exists()  # refused before any work


def test_api_mistakes_name_the_parameter(files) -> None:
    inst = Instrument.paper(sigma=PAPER_SIGMA_662)
    with pytest.raises(ParameterError, match="instrument must be an Instrument, got NoneType"):
        get_model("exact").profile(None, [1.0], [0.0], [0.0])
    # A fixed attenuation does not make a nonsensical energy acceptable.
    # A profile is at one energy (the attenuation calls also take many: not here).
    for bad in (np.nan, -5.0, [662.0], [122.0, 662.0]):
        with pytest.raises(ParameterError, match="energy must be"):
            get_model("exact").profile(inst, [1.0], [0.0], [0.0], energy=bad)


def test_folded_files_with_no_rows_or_gapped_bins_are_refused(files, tmp_path) -> None:
    with fits.open(files / "f.fits") as h:
        h["PROFILES"].data = h["PROFILES"].data[:0]
        h.writeto(tmp_path / "empty.fits", checksum=True)
    with pytest.raises(RotmodError, match="PROFILES table has no rows"):
        read_folded(tmp_path / "empty.fits")
    with fits.open(files / "f.fits") as h:
        h["PROFILES"].data["BIN_HI"][3] += 1.0
        h.writeto(tmp_path / "gap.fits", checksum=True)
    with pytest.raises(RotmodError, match="not contiguous"):
        read_folded(tmp_path / "gap.fits")


def test_folded_bins_must_be_the_response_bins(files) -> None:
    f = read_folded(files / "f.fits")
    resp = build_response(f.instrument, SkyGrid((3, 3), 1.0), TimeBinning(12), energy=122)
    # Same number of bins, other edges (a quarter-bin shift): refused, not fitted silently
    # (folded profiles hold a TimeBinning, so such edges are refused as they are converted).
    with pytest.raises(ParameterError, match="must be 12 equal bins over a turn"):
        TimeBinning.from_edges(f.bin_edges + 7.5 * f.bin_edges.unit / 57.3)
    # Other bins than the response's: refused, not fitted silently.
    other = FoldedProfiles(np.ones((f.counts.shape[0], 24), int), np.ones(24), 24,
                           f.instrument, f.gti)
    with pytest.raises(ParameterError, match="not the response's time bins"):
        reconstruct(resp, other, "mlem", max_iter=2)
    reconstruct(resp, f, "mlem", max_iter=2)  # the file's own bins are accepted


def test_a_flipped_bit_in_a_file_rotmod_wrote_is_detected(files, tmp_path) -> None:
    from rotmod.io import read_events

    data = bytearray((files / "ev.fits").read_bytes())
    with fits.open(files / "ev.fits") as h:
        off = h.fileinfo(h.index_of("GTI"))["datLoc"] + 3
    data[off] ^= 0x10  # one bit of a GTI boundary: would change the exposure silently
    (tmp_path / "ev.fits").write_bytes(bytes(data))
    with pytest.raises(RotmodError, match=r"is corrupt: .*GTI"):
        read_events(tmp_path / "ev.fits")


@pytest.mark.parametrize(
    ("argv", "what"),
    [
        (["response", "--fov", "100", "--pixel", "0.0001", "-o", "{d}/big.zarr"],
         "projecting 1000000000000 sky pixels"),
        (["profile", "-s", "6,0", "--angles", "1e12", "-o", "{d}/big.csv"], "1000000000000"),
        (["fold", "{d}/ev.fits", "-n", "1e12", "-o", "{d}/big.fits"], "1000000000000 time bins"),
        (["response", "-n", "1e12", "-o", "{d}/big2.zarr"], "1000000000000 time bins"),
        (["simulate", "-s", "3,0,10", "-t", "1e12", "-o", "{d}/big.fits"],
         "an observation of 1e\\+12 s"),
    ],
)
def test_huge_requests_are_refused_up_front(capsys, files, argv, what) -> None:
    # Each of these used to allocate until MemoryError (or for minutes); now the estimate is
    # compared with the budget before anything is allocated.
    code, err = _cli(capsys, *(a.format(d=files) for a in argv))
    assert code == 2 and "Traceback" not in err, err
    assert re.search(rf"{what}.* needs about .* more than rotmod's memory budget", err), err
    assert not list(files.glob("big*"))


def test_a_store_larger_than_the_free_disk_is_refused_up_front(capsys, monkeypatch,
                                                              tmp_path) -> None:
    # `rotmod response --pixel 0.001` (a ~440 GB store) used to start computing; now the
    # store's size is compared with the free space first.  The free space is set to 1 GiB:
    # 1400 x 1400 pixels x 560 bins x 4 B = 4.4 GB for one detector.
    monkeypatch.setattr(shutil, "disk_usage",
                        lambda path: SimpleNamespace(total=2**40, used=2**40 - 2**30, free=2**30))
    code, err = _cli(capsys, "response", "--fov", "14", "--pixel", "0.01",
                     "-o", tmp_path / "big.zarr")
    assert code == 2 and "Traceback" not in err, err
    assert re.search(r"a response store of 1 detector\(s\) x \d+ time bins x 1960000 pixels "
                     r"float32 needs up to .* of disk \(uncompressed\), more than the 1\.00 GiB "
                     r"free at '.*big\.zarr'; use larger pixels", err), err
    assert list(tmp_path.iterdir()) == []  # no store, no .partial, no lock


def test_budget_is_configurable_and_checked(monkeypatch, tmp_path) -> None:
    from rotmod.config import InstrumentConfig
    from rotmod.limits import MemoryBudgetError, memory_budget

    monkeypatch.setenv("ROTMOD_MEMORY_BUDGET", "1 MiB")
    assert memory_budget() == 2**20
    with pytest.raises(MemoryBudgetError, match=r"profiles of 1 detectors x 1000 angles x 200"):
        get_model("exact").profile(Instrument.paper(), np.zeros(200), np.zeros(200),
                                   np.zeros(1000), energy=662)
    monkeypatch.setenv("ROTMOD_MEMORY_BUDGET", "lots")
    with pytest.raises(MemoryBudgetError, match="ROTMOD_MEMORY_BUDGET must be an amount"):
        memory_budget()
    monkeypatch.delenv("ROTMOD_MEMORY_BUDGET")
    # 100000 rings would be 3e10 detectors: refused at once, not looped over for minutes.
    d = {"mask": {"slat_width": "4 cm", "slat_gap": "4 cm", "thickness": "2 cm",
                  "height": "1 m"},
         "detectors": {"layout": "hexagonal", "diameter": "4 cm", "rings": 100000}}
    with pytest.raises(RotmodError, match="hexagonal array of 100000 rings"):
        InstrumentConfig.from_dict(d)


def test_unicode_paths_work_in_every_command(capsys, files, tmp_path) -> None:
    import shutil
    from urllib.parse import unquote

    from rotmod.io.images import read_image

    d = tmp_path / "données ré"
    d.mkdir()
    shutil.copytree(files / "r.zarr", d / "ré.zarr")
    code, err = _cli(capsys, "fold", files / "ev.fits", "-n", "12", "-o", d / "plié.fits")
    assert code == 0, err
    code, err = _cli(capsys, "reconstruct", d / "plié.fits", d / "ré.zarr", "-o",
                     d / "image é.fits", "--plot", d / "image é.png")
    assert code == 0, err
    img = read_image(d / "image é.fits")
    # The path goes into the header percent-encoded (FITS headers are ASCII), reversibly.
    assert unquote(img.header["RESPONSE"]) == str(d / "ré.zarr")
    assert (d / "image é.png").stat().st_size > 0


def _edit_events(src, dst, fn):
    with fits.open(src) as h:
        fn(h)
        h.writeto(dst, checksum=True)


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda h: h["EVENTS"].header.set("MASK_A", "abc"), "keyword MASK_A must be a number"),
        (lambda h: h["EVENTS"].header.set("MJDREFI", "xx"), "keyword MJDREFI must be a number"),
        (lambda h: h["EVENTS"].header.set("TIMEUNIT", "furlong"),
         "TIMEUNIT must be a time unit"),
    ],
)
def test_event_files_from_elsewhere_with_bad_keywords(files, tmp_path, edit, match) -> None:
    from rotmod.io import read_events

    _edit_events(files / "ev.fits", tmp_path / "bad.fits", edit)
    with pytest.raises(RotmodError, match=match):
        read_events(tmp_path / "bad.fits")


def test_ogip_time_keywords_are_honoured(files, tmp_path) -> None:
    from rotmod.io import read_events

    ref = read_events(files / "ev.fits")

    def to_ms_with_offset(h):
        # The same events written in milliseconds with a 100 s TIMEZERO.
        ev = h["EVENTS"]
        cols = ev.columns
        t = np.asarray(ev.data["TIME"]) * 1000.0 - 100e3
        new = fits.ColDefs([fits.Column("TIME", "D", unit="ms", array=t)]
                           + [c for c in cols if c.name != "TIME"])
        hdr = ev.header.copy()
        hdr["TIMEZERO"] = (100.0, "[s]")
        hdr["TSTART"] = ev.header["TSTART"] - 100.0
        hdr["TSTOP"] = ev.header["TSTOP"] - 100.0
        h["EVENTS"] = fits.BinTableHDU.from_columns(new, header=hdr, name="EVENTS")
        g = h["GTI"]
        g.header["TIMEZERO"] = 100.0
        g.data["START"] -= 100.0
        g.data["STOP"] -= 100.0

    _edit_events(files / "ev.fits", tmp_path / "ms.fits", to_ms_with_offset)
    back = read_events(tmp_path / "ms.fits")
    # ms -> s and the 100 s offset: round-off of the two operations only (1e-9 s).
    np.testing.assert_allclose(back.time, ref.time, rtol=0, atol=1e-9)
    np.testing.assert_allclose(back.gti, ref.gti, rtol=0, atol=1e-9)
    assert back.t_start == pytest.approx(ref.t_start) and back.meta["timezero"] == 0.0


def test_a_string_time_column_is_refused(files, tmp_path) -> None:
    from rotmod.io import read_events

    def string_time(h):
        ev = h["EVENTS"]
        cols = [fits.Column("TIME", "10A", array=np.char.mod("%.3f", ev.data["TIME"]))]
        cols += [c for c in ev.columns if c.name != "TIME"]
        h["EVENTS"] = fits.BinTableHDU.from_columns(cols, header=ev.header, name="EVENTS")

    _edit_events(files / "ev.fits", tmp_path / "s.fits", string_time)
    with pytest.raises(RotmodError, match="column TIME must be numeric"):
        read_events(tmp_path / "s.fits")


def test_a_response_for_another_energy_is_refused(capsys, files, tmp_path) -> None:
    # The events are a 122 keV line; the folded file records the band; a 662 keV response
    # (other slat attenuation) used to run silently on them.
    f = read_folded(files / "f.fits")
    band = f.energy_band
    assert band.e_min == pytest.approx(122.0) and band.e_max == pytest.approx(122.0)
    grid = SkyGrid((3, 3), 1.0)
    with pytest.raises(ParameterError, match=r"made for 662 keV.*band 122-122 keV"):
        reconstruct(build_response(f.instrument, grid, 12, energy=662), f, max_iter=2)
    reconstruct(build_response(f.instrument, grid, 12, energy=122), f, max_iter=2)
    # An explicit window on the command line, with units.
    code, err = _cli(capsys, "fold", files / "ev.fits", "-n", "12", "--band", "100:0.14MeV",
                     "-o", tmp_path / "w.fits")
    assert code == 0, err
    w = read_folded(tmp_path / "w.fits")
    assert (w.energy_band.e_min, w.energy_band.e_max) == pytest.approx((100.0, 140.0))
    assert w.counts.sum() == f.counts.sum()  # the line lies inside the window
    code, err = _cli(capsys, "fold", files / "ev.fits", "--band", "140:100",
                     "-o", tmp_path / "x.fits")
    assert code == 2 and "energy_band must be (lo, hi)" in err


def test_standard_model_refuses_zero_thickness_slats_that_stop_nothing() -> None:
    from rotmod import DetectorArray, Mask
    from rotmod.errors import ModelValidityError

    inst = Instrument(Mask(4.0, 4.0, 0.0, 100.0, "lead"), DetectorArray.single(4.0))
    with pytest.raises(ModelValidityError, match=r"thickness = 0 cm with a finite attenuation"):
        get_model("standard").profile(inst, [2.0], [0.0], [0.0], energy=662)
    # The paper's thin opaque mask (mu = inf) is exactly the standard model's domain.
    thin = Instrument(Mask(4.0, 4.0, 0.0, 100.0, "lead", mu=np.inf), DetectorArray.single(4.0))
    get_model("standard").profile(thin, [2.0], [0.0], [0.0])


def test_binary_instrument_files_and_absurd_heights(capsys, tmp_path) -> None:
    from rotmod import Mask

    binary = tmp_path / "inst.toml"
    binary.write_bytes(bytes(range(256)))
    code, err = _cli(capsys, "profile", "-i", binary, "-s", "6,0", "-o", tmp_path / "p.csv")
    assert code == 2 and "Traceback" not in err and "is not a text file" in err, err
    with pytest.raises(ParameterError, match=r"mask\.height must be <= 1e9 slat periods"):
        Mask(4.0, 4.0, 2.0, 1e12, "lead")
    with pytest.raises(ParameterError, match=r"mask\.axis_offset_y must be within 1e9 slat"):
        Mask(4.0, 4.0, 2.0, 100.0, "lead", axis_offset_y=-1e30)
