"""OGIP spectra: rotmod's PHA/RMF/ARF files read back exactly, refused safely, and read and fitted
by real clients (gammapy, threeML, sherpa) to the same parameters."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import astropy.units as u
import numpy as np
import pytest
from astropy.io import fits

import rotmod.io
from rotmod.errors import ParameterError, RotmodError
from rotmod.io.ogip import ogip_paths, read_ogip
from rotmod.spectral import CountsSpectrum, PowerLaw, RateSpectrum, fit_spectrum
from tests.io.conftest import ogip_rate_spectrum, ogip_spectrum


def test_round_trip(tmp_path) -> None:
    """Counts, exposure, scaling and the response come back (the matrix at float32 precision,
    the format's); the four files carry OGIP's class cards.  Source and background differ in
    exposure and BACKSCAL, so a swapped or lost ratio shows."""
    base = ogip_spectrum()
    bkg = CountsSpectrum(base.background.counts, 3e4, backscal=4.0)
    spec = CountsSpectrum(base.counts, 1e4, base.response, bkg, backscal=0.5, meta=base.meta)
    path = rotmod.io.write(spec, tmp_path / "src.pha")
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "src.arf", "src.pha", "src.rmf", "src_bkg.pha"]
    back = rotmod.io.read(path)
    assert np.array_equal(back.counts, spec.counts)
    assert back.exposure == 1e4 and back.backscal == 0.5
    assert back.background.exposure == 3e4 and back.background.backscal == 4.0
    assert np.array_equal(back.background.counts, spec.background.counts)
    assert back.background_ratio == pytest.approx((0.5 * 1e4) / (4.0 * 3e4))
    np.testing.assert_allclose(back.response.matrix, spec.response.matrix, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(back.response.energy_edges, spec.response.energy_edges, rtol=1e-7)
    np.testing.assert_allclose(back.response.area, spec.response.area, rtol=1e-7)
    with fits.open(tmp_path / "src.rmf") as h:
        assert h["MATRIX"].header["HDUCLAS3"] == "REDIST"
        assert h["MATRIX"].header["HDUCLASS"] == "OGIP"
    with fits.open(path) as h:
        assert h["SPECTRUM"].header["RESPFILE"] == "src.rmf"
        assert h["SPECTRUM"].header["BACKFILE"] == "src_bkg.pha"


def test_gammapy_reads_and_fits_the_same_parameters(tmp_path) -> None:
    """gammapy (a real OGIP client) predicts the same counts for the same model (1e-6: the
    files store float32) and fits the same index and amplitude with the same W statistic
    (within 1e-3 of the errors' scale; the issue asks 1 %)."""
    datasets = pytest.importorskip("gammapy.datasets")
    models = pytest.importorskip("gammapy.modeling.models")
    modeling = pytest.importorskip("gammapy.modeling")
    spec = ogip_spectrum()
    rotmod.io.write(spec, tmp_path / "src.pha")
    ours = fit_spectrum(rotmod.io.read(tmp_path / "src.pha"), PowerLaw(2e-4, -1.5))
    ds = datasets.SpectrumDatasetOnOff.read(tmp_path / "src.pha")
    pl = models.PowerLawSpectralModel(index=1.5, amplitude="2e-4 cm-2 s-1 keV-1",
                                      reference="100 keV")
    ds.models = [models.SkyModel(spectral_model=pl)]
    np.testing.assert_allclose(
        ds.npred_signal().data.ravel(),
        spec.response.fold(PowerLaw(2e-4, -1.5), spec.exposure), rtol=1e-6)
    result = modeling.Fit().run([ds])
    assert result.success
    # Same maximum: within 1 % of an error (measured 0.4 %), 250x tighter than the 1 %.
    assert -pl.index.value == pytest.approx(ours.model.index, abs=1e-2 * ours.errors["index"])
    assert pl.amplitude.value == pytest.approx(ours.model.K, abs=1e-2 * ours.errors["K"])
    assert pl.index.error == pytest.approx(ours.errors["index"], rel=1e-2)
    assert ds.stat_sum() == pytest.approx(ours.statistic, rel=1e-4)


def test_refusals_leave_files_alone(tmp_path) -> None:
    """An existing sidecar (here the RMF) is refused by name before anything is written; a PHA
    path must say it is one; a corrupt sidecar is an error naming it."""
    spec = ogip_spectrum()
    (tmp_path / "src.rmf").write_text("mine")
    with pytest.raises(ParameterError, match=r"RMF file .*src\.rmf.* already exists"):
        rotmod.io.write(spec, tmp_path / "src.pha")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src.rmf"]
    assert (tmp_path / "src.rmf").read_text() == "mine"
    with pytest.raises(ParameterError, match=r"must end in \.pha or \.pi"):
        ogip_paths(tmp_path / "src.fits")
    rotmod.io.write(spec, tmp_path / "b.pha")
    data = bytearray((tmp_path / "b.arf").read_bytes())
    data[-100] ^= 0xFF
    (tmp_path / "b.arf").write_bytes(bytes(data))
    with pytest.raises(RotmodError, match=r"b\.arf"):
        rotmod.io.read(tmp_path / "b.pha")


def test_what_the_reader_cannot_honour_is_refused(tmp_path) -> None:
    """Bad-quality channels, per-channel BACKSCAL and a missing EXPOSURE are refused by name,
    never dropped."""
    path = rotmod.io.write(ogip_spectrum(), tmp_path / "s.pha")
    for column, value, message in (("QUALITY", 5, "QUALITY"), ("BACKSCAL", None, "BACKSCAL")):
        with fits.open(path) as h:
            data = h["SPECTRUM"].data
            if value is None:
                data[column][3] = 7.0
            else:
                data[column][3] = value
            h.writeto(tmp_path / "t.pha", overwrite=True, checksum=True)
        for side in ("rmf", "arf"):
            (tmp_path / f"t.{side}").write_bytes((tmp_path / f"s.{side}").read_bytes())
        with pytest.raises(ParameterError, match=message):
            rotmod.io.read(tmp_path / "t.pha", cls=CountsSpectrum)
    with fits.open(path) as h:
        del h["SPECTRUM"].header["EXPOSURE"]
        h.writeto(tmp_path / "u.pha", overwrite=True, checksum=True)
    with pytest.raises(ParameterError, match="no EXPOSURE"):
        rotmod.io.read(tmp_path / "u.pha", cls=CountsSpectrum)


def test_rate_spectrum_round_trip(tmp_path) -> None:
    """Rates with Gaussian errors (an extracted spectrum) come back as a RateSpectrum: rates
    and errors exactly (double columns), the response at float32 precision; the PHA says
    RATE, STAT_ERR and POISSERR = F, names no background, and both ``read`` and
    ``read(cls=RateSpectrum)`` find it.  The chi-square fit of the file's contents is the
    fit of the spectrum written (1e-3 of an error: the matrix's float32 rounding)."""
    spec = ogip_rate_spectrum()
    path = rotmod.io.write(spec, tmp_path / "src.pha")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src.arf", "src.pha", "src.rmf"]
    back = rotmod.io.read(path)
    assert isinstance(back, RateSpectrum)
    assert isinstance(rotmod.io.read(path, cls=RateSpectrum), RateSpectrum)
    assert np.array_equal(back.rate, spec.rate) and np.array_equal(back.error, spec.error)
    assert back.exposure == spec.exposure
    np.testing.assert_allclose(back.response.matrix, spec.response.matrix, rtol=1e-7,
                               atol=1e-12)
    np.testing.assert_allclose(back.response.area, spec.response.area, rtol=1e-7)
    with fits.open(path) as h:
        s = h["SPECTRUM"]
        assert s.header["POISSERR"] is False and s.header["HDUCLAS3"] == "RATE"
        assert s.header["BACKFILE"] == "none"
        assert {"RATE", "STAT_ERR"} <= set(s.columns.names) and "COUNTS" not in s.columns.names
    ours = fit_spectrum(spec, PowerLaw(2e-4, -1.5))
    read = fit_spectrum(back, PowerLaw(2e-4, -1.5))
    assert ours.stat_name == read.stat_name == "chi2"
    assert read.model.index == pytest.approx(ours.model.index, abs=1e-3 * ours.errors["index"])
    assert read.errors["index"] == pytest.approx(ours.errors["index"], rel=1e-3)


def test_rate_spectra_the_reader_cannot_honour_are_refused(tmp_path) -> None:
    """Gaussian data without errors, Poisson rates, systematic errors and a background file
    beside extracted rates are refused by name; COUNTS with STAT_ERR and POISSERR = F are
    read as rates (counts / exposure)."""
    path = rotmod.io.write(ogip_rate_spectrum(), tmp_path / "s.pha")

    def edited(name: str, edit) -> Path:
        with fits.open(path) as h:
            edit(h)
            h.writeto(tmp_path / f"{name}.pha", overwrite=True, checksum=True)
        for side in ("rmf", "arf"):
            (tmp_path / f"{name}.{side}").write_bytes((tmp_path / f"s.{side}").read_bytes())
        return tmp_path / f"{name}.pha"

    def no_errors(h):
        h["SPECTRUM"].columns.del_col("STAT_ERR")
    def poisson(h):
        h["SPECTRUM"].header["POISSERR"] = True
    def systematic(h):
        h["SPECTRUM"].header["SYS_ERR"] = 0.03
    def background(h):
        h["SPECTRUM"].header["BACKFILE"] = "s.pha"
    for name, edit, message in (("a", no_errors, "STAT_ERR"), ("b", poisson, "POISSERR = T"),
                                ("c", systematic, "SYS_ERR"), ("d", background,
                                                               "background file")):
        with pytest.raises(ParameterError, match=message):
            read_ogip(edited(name, edit))
    spec = ogip_rate_spectrum()

    def as_counts(h):
        d = h["SPECTRUM"]
        cols = [c for c in d.columns if c.name not in ("RATE", "STAT_ERR")]
        new = fits.BinTableHDU.from_columns(
            [*cols, fits.Column("COUNTS", "D", array=spec.rate * 1e4),
             fits.Column("STAT_ERR", "D", array=spec.error * 1e4)], header=d.header,
            name="SPECTRUM")
        h["SPECTRUM"] = new
    back = read_ogip(edited("e", as_counts))
    np.testing.assert_allclose(back.rate, spec.rate, rtol=1e-15)
    np.testing.assert_allclose(back.error, spec.error, rtol=1e-15)


def test_gammapy_reads_a_rate_spectrum_and_fits_the_same_parameters(tmp_path) -> None:
    """gammapy's OGIP dataset reader refuses a RATE spectrum (it knows COUNTS only, so it
    cannot fit Poisson statistics to extracted rates by mistake).  Its pieces read the files:
    the RATE and STAT_ERR columns as written, the ARF and RMF predicting our folded counts
    (1e-6: the files' float32), and a chi-square fit with gammapy's model integration,
    folding and optimiser (Minuit) gives our index, amplitude and error within 1 % of an
    error (measured 0.3 %) and the same chi-square."""
    datasets = pytest.importorskip("gammapy.datasets")
    gio = pytest.importorskip("gammapy.datasets.io")
    maps = pytest.importorskip("gammapy.maps")
    models = pytest.importorskip("gammapy.modeling.models")
    modeling = pytest.importorskip("gammapy.modeling")
    spec = ogip_rate_spectrum()
    path = rotmod.io.write(spec, tmp_path / "src.pha")
    with pytest.raises(KeyError, match="COUNTS"):
        datasets.SpectrumDatasetOnOff.read(path)
    with fits.open(path) as h:
        rate = maps.RegionNDMap.from_hdulist(h, format="ogip", ogip_column="RATE")
        err = maps.RegionNDMap.from_hdulist(h, format="ogip", ogip_column="STAT_ERR")
    np.testing.assert_array_equal(rate.data.ravel(), spec.rate)
    expo = gio.OGIPDatasetReader.read_arf(tmp_path / "src.arf", livetime=spec.exposure * u.s)
    edisp = gio.OGIPDatasetReader.read_rmf(tmp_path / "src.rmf", exposure=expo)

    class Chi2Dataset(datasets.SpectrumDataset):
        def stat_sum(self) -> float:
            sigma = err.data * spec.exposure
            return float(np.sum(((self.counts.data - self.npred().data) / sigma) ** 2))

    ds = Chi2Dataset(counts=rate * spec.exposure, exposure=expo, edisp=edisp)
    pl = models.PowerLawSpectralModel(index=1.5, amplitude="2e-4 cm-2 s-1 keV-1",
                                      reference="100 keV")
    ds.models = [models.SkyModel(spectral_model=pl)]
    np.testing.assert_allclose(ds.npred_signal().data.ravel(),
                               spec.response.fold(PowerLaw(2e-4, -1.5), spec.exposure),
                               rtol=1e-6)
    result = modeling.Fit().run([ds])
    ours = fit_spectrum(spec, PowerLaw(2e-4, -1.5))
    assert result.success
    assert -pl.index.value == pytest.approx(ours.model.index, abs=1e-2 * ours.errors["index"])
    assert pl.amplitude.value == pytest.approx(ours.model.K, abs=1e-2 * ours.errors["K"])
    assert pl.index.error == pytest.approx(ours.errors["index"], rel=1e-2)
    assert ds.stat_sum() == pytest.approx(ours.statistic, rel=1e-4)


@pytest.mark.parametrize("client", ["threeml", "sherpa"])
def test_clients_read_and_fit_the_same_parameters(client, tmp_path) -> None:
    """threeML (OGIPLike, Minuit) and sherpa (load_pha, levmar) read both kinds of spectrum
    as they are: the counts with their Poisson background (threeML's ``poisson``/``poisson``,
    sherpa's ``wstat``) and the extracted rates with their errors (``gaussian``, ``chi2``).
    Each folds our counts for the same model (1e-6: the files' float32) and fits our index
    and amplitude within 1 % of an error (measured: threeML 2e-5, sherpa 1.5e-4), with our
    errors within 1 % (measured 1e-5 and 2e-6; the issue asks the parameters within 1 %) and,
    for the rates, our chi-square (1e-6).  Run in a process of their own
    (tests/io/ogip_clients.py).  threeML is in the test extra; sherpa has no wheel here (its
    sdist needs a compiler, byacc and FFTW), so its case runs where it is installed."""
    module = {"threeml": "threeML", "sherpa": "sherpa"}[client]
    if importlib.util.find_spec(module) is None:
        pytest.skip(f"{module} is not installed")
    counts, rates = ogip_spectrum(), ogip_rate_spectrum()
    paths = []
    for kind, spec in [("counts", counts), ("rate", rates)]:
        (tmp_path / kind).mkdir()
        paths.append(rotmod.io.write(spec, tmp_path / kind / "src.pha"))
    run = subprocess.run([sys.executable, str(Path(__file__).with_name("ogip_clients.py")),
                          client, *map(str, paths)], capture_output=True, text=True,
                         timeout=600, check=False, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]
    got = [json.loads(line) for line in run.stdout.splitlines() if line.startswith("{")]
    assert [g["statistic"] for g in got] == {
        "threeml": [["poisson", "poisson"], ["gaussian", None]],
        "sherpa": [["wstat", None], ["chi2", None]]}[client]
    for spec, g in zip([counts, rates], got, strict=True):
        np.testing.assert_allclose(g["folded"], spec.response.fold(PowerLaw(2e-4, -1.5),
                                                                   spec.exposure), rtol=1e-6)
        ours = fit_spectrum(spec, PowerLaw(2e-4, -1.5))
        assert g["index"] == pytest.approx(ours.model.index, abs=1e-2 * ours.errors["index"])
        assert g["K"] == pytest.approx(ours.model.K, abs=1e-2 * ours.errors["K"])
        assert g["index_error"] == pytest.approx(ours.errors["index"], rel=1e-2)
        assert g["K_error"] == pytest.approx(ours.errors["K"], rel=1e-2)
    assert got[1]["value"] == pytest.approx(fit_spectrum(rates, PowerLaw(2e-4, -1.5)).statistic,
                                            rel=1e-6)
    if client == "sherpa":    # sherpa's wstat is our W statistic itself
        assert got[0]["value"] == pytest.approx(fit_spectrum(counts, PowerLaw(2e-4, -1.5))
                                                .statistic, rel=1e-6)
