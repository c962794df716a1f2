"""The threeML plugin: rotmod's spectral likelihood of the modulator's counts inside threeML,
alone (the parameters and errors of :func:`fit_spectra`) and in a joint fit with another
instrument's OGIP spectrum read by threeML's own plugin."""

from __future__ import annotations

import warnings

import matplotlib
import numpy as np
import pytest

import rotmod.io
from rotmod.errors import ParameterError
from rotmod.sources.spectra import expected_counts, fit_spectra
from rotmod.spectral import CountsSpectrum, PowerLaw
from tests.spectral.test_spectrum import gaussian_response

#: threeML's results table trips a pandas deprecation inside threeML (not ours to mend).
pytestmark = pytest.mark.filterwarnings("ignore:Setting an item of incompatible dtype")

TRUTH = PowerLaw(1e-3, -2.0)
EXPOSURE = np.full(24, 500.0)


@pytest.fixture(scope="module")
def threeml():
    """threeML and astromodels, and what importing threeML changes for the whole process
    restored after this module: matplotlib's style and ``warnings.formatwarning`` (pytest
    restores the warning filters itself, per test)."""
    format_warning = warnings.formatwarning
    try:
        with matplotlib.rc_context():
            threeml = pytest.importorskip("threeML")
            astromodels = pytest.importorskip("astromodels")
            from rotmod.sources.threeml import RotmodLike
            yield threeml, astromodels, RotmodLike
    finally:
        warnings.formatwarning = format_warning


def _fit(threeml, astromodels, plugins, names=("src",)):
    """A threeML fit of power laws named ``names`` to ``plugins``: its models' shapes and
    the fit's parameter errors from its covariance (K in threeML's log10 K)."""
    shapes = [astromodels.Powerlaw(K=2e-3, index=-1.5, piv=100.0) for _ in names]
    model = astromodels.Model(*[astromodels.PointSource(n, 0.0, 0.0, spectral_shape=s)
                                for n, s in zip(names, shapes, strict=True)])
    fitter = threeml.JointLikelihood(model, threeml.DataList(*plugins), verbose=False)
    minimizer = threeml.LocalMinimization("minuit")
    minimizer.setup(ftol=1e-6)   # Minuit's default stops ~1 % of an error short
    fitter.set_minimizer(minimizer)
    fitter.fit(quiet=True)
    sigma = dict(zip(model.free_parameters,
                     np.sqrt(np.diag(fitter.results.covariance_matrix)), strict=True))
    errors = [{"K": sigma[s.K.path] * s.K.value * np.log(10.0), "index": sigma[s.index.path]}
              for s in shapes]
    return shapes, errors


def test_threeml_fits_the_modulator_as_fit_spectra(threeml, columns) -> None:
    """threeML with the plugin alone finds fit_spectra's maximum (index and K within 1 % of
    an error) with its errors (1 %) and log-likelihood (1e-9 relative): the same likelihood,
    the same profiled background, spectra folded by quadrature of astromodels' power law."""
    three, astro, RotmodLike = threeml
    rng = np.random.default_rng(5)
    y = rng.poisson(expected_counts(columns, EXPOSURE, [TRUTH], background=0.04))
    ours = fit_spectra(columns, y, EXPOSURE, [PowerLaw(2e-3, -1.5)])
    plugin = RotmodLike("rm", columns, y, EXPOSURE, "src")
    (shape,), (errors,) = _fit(three, astro, [plugin])
    assert shape.index.value == pytest.approx(ours.models[0].index,
                                              abs=1e-2 * ours.errors[0]["index"])
    assert shape.K.value == pytest.approx(ours.models[0].K, abs=1e-2 * ours.errors[0]["K"])
    assert errors["index"] == pytest.approx(ours.errors[0]["index"], rel=1e-2)
    assert errors["K"] == pytest.approx(ours.errors[0]["K"], rel=1e-2)
    assert plugin.get_log_like() == pytest.approx(ours.loglike, rel=1e-9)
    assert plugin.get_number_of_data_points() == y.size


def test_two_sources_and_a_joint_fit_with_another_instrument(threeml, two_sources, tmp_path
                                                             ) -> None:
    """Two sources, each named in the model, are fitted as fit_spectra fits them (1 % of an
    error).  Joined with an OGIP spectrum of the first source by another instrument (read by
    threeML's OGIPLike), that source's index error shrinks below both instruments' alone and
    the joint maximum is the best of both likelihoods: each instrument's own best for that
    source has a lower sum of the two plugins' ln L."""
    three, astro, RotmodLike = threeml
    second = PowerLaw(2e-3, -2.5)
    rng = np.random.default_rng(6)
    y = rng.poisson(expected_counts(two_sources, EXPOSURE, [TRUTH, second], background=0.04))
    ours = fit_spectra(two_sources, y, EXPOSURE, [PowerLaw(2e-3, -1.5)] * 2)
    rm = RotmodLike("rm", two_sources, y, EXPOSURE, ["a", "b"])
    shapes, errors = _fit(three, astro, [rm], names=("a", "b"))
    for shape, err, mine, mine_err in zip(shapes, errors, ours.models, ours.errors,
                                          strict=True):
        assert shape.index.value == pytest.approx(mine.index, abs=1e-2 * mine_err["index"])
        assert err["index"] == pytest.approx(mine_err["index"], rel=1e-2)
    # Another instrument's spectrum of source "a": 1000 s through a Gaussian-resolution
    # response (~4e4 counts) on a flat background measured in a region twice as large.
    r = gaussian_response()
    bkg = CountsSpectrum(rng.poisson(np.full(48, 5.0)), 1e3, backscal=2.0)
    other = CountsSpectrum(rng.poisson(r.fold(TRUTH, 1e3) + 2.5), 1e3, r, bkg)
    path = rotmod.io.write(other, tmp_path / "other.pha")
    ogip = three.OGIPLike("other", observation=str(path), background=str(tmp_path /
                          "other_bkg.pha"), response=str(tmp_path / "other.rmf"),
                          arf_file=str(tmp_path / "other.arf"))
    ogip.assign_to_source("a")   # a spectrum plugin otherwise sums every source
    alone, alone_err = _fit(three, astro, [ogip], names=("a",))
    joint, joint_err = _fit(three, astro, [rm, ogip], names=("a", "b"))
    assert joint_err[0]["index"] < min(errors[0]["index"], alone_err[0]["index"])
    ll_joint = rm.get_log_like() + ogip.get_log_like()
    for shape in (shapes[0], alone[0]):   # each instrument's own best for source "a"
        joint[0].K.value, joint[0].index.value = shape.K.value, shape.index.value
        assert rm.get_log_like() + ogip.get_log_like() < ll_joint


def test_log_like_is_a_function_of_the_parameters(threeml, columns) -> None:
    """threeML recomputes its minimum and compares it bit for bit: the first evaluation of a
    new plugin equals every later one at the same parameters, whatever came between; a
    spectrum that overflows at the node energies is -inf, not an error."""
    _, astro, RotmodLike = threeml
    y = np.random.default_rng(7).poisson(
        expected_counts(columns, EXPOSURE, [TRUTH], background=0.04))
    plugin = RotmodLike("rm", columns, y, EXPOSURE, "src")
    shape = astro.Powerlaw(K=1e-3, index=-2.0, piv=100.0)
    plugin.set_model(astro.Model(astro.PointSource("src", 0.0, 0.0, spectral_shape=shape)))
    first = plugin.get_log_like()
    shape.index.value = -1.5
    assert plugin.get_log_like() != first
    shape.index.value = -2.0
    assert plugin.get_log_like() == first
    shape.K.max_value = None                         # astromodels caps K at 1000
    shape.K.value, shape.index.value = 1e308, -10.0  # 1e308 (60 keV / 100 keV)^-10 overflows
    assert plugin.get_log_like() == -np.inf


def test_bad_input_is_named(threeml, columns) -> None:
    _, astro, RotmodLike = threeml
    y = np.zeros(columns.shape)
    with pytest.raises(ParameterError, match="sources must name"):
        RotmodLike("rm", columns, y, EXPOSURE, ["a", "b"])
    with pytest.raises(ParameterError, match="counts must have shape"):
        RotmodLike("rm", columns, y[:, :3], EXPOSURE, "a")
    plugin = RotmodLike("rm", columns, y, EXPOSURE, "a")
    with pytest.raises(ParameterError, match="set_model first"):
        plugin.get_log_like()
    model = astro.Model(astro.PointSource("b", 0.0, 0.0, spectral_shape=astro.Powerlaw()))
    with pytest.raises(ParameterError, match="no point source 'a'"):
        plugin.set_model(model)
    with pytest.raises(ParameterError, match="likelihood_model_instance must be an"):
        plugin.set_model({"a": None})
