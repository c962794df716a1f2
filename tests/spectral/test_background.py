"""The balloon background (rotmod.spectral.background) against published numbers, closed forms
of the folding, conservation and the physics' monotonic trends."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.integrate import quad, simpson

from rotmod import DetectorArray, Mask, Material
from rotmod.errors import ParameterError
from rotmod.spectral.atmosphere import Atmosphere
from rotmod.spectral.background import (
    MIZUNO_DEPTH,
    BalloonBackground,
    angular_shape_downward,
    angular_shape_upward,
    annihilation_line,
    atmospheric_continuum,
    cxb_intensity,
    diffuse_rates,
    fit_normalisations,
    internal_rates,
    mask_transmission,
)
from rotmod.spectral.detector import DetectorResponse
from rotmod.spectral.models import Gaussian, PowerLaw

NAI = Material("NaI", density=3.67)


def _black(radius=2.5, thickness=5.0, energies=(100.0, 300.0, 1000.0), angles=None,
           rows=None):
    """A black cylinder: every photon crossing it interacts (E0 = the shadow over the top
    face, 1 + 2 H tan(theta) / (pi R)), counted in the channel of its true energy."""
    det = DetectorArray([[0.0, 0.0]], 2 * radius, thickness, NAI)
    ang = np.array([0.0, 20.0, 40.0, 60.0, 75.0, 85.0, 89.0] if angles is None else angles)
    e = np.array(energies)
    inter = np.repeat((1.0 + 2 * thickness * np.tan(np.radians(ang)) / (math.pi * radius))
                      [:, None], e.size, axis=1)
    ln = np.log(e)
    mid = 0.5 * (ln[1:] + ln[:-1])
    ch = np.exp(np.concatenate([[2 * ln[0] - mid[0]], mid, [2 * ln[-1] - mid[-1]]]))
    mat = np.repeat(np.diag(np.ones(e.size) if rows is None else rows)[None], ang.size, axis=0)
    resp = DetectorResponse(ang, e, ch, inter, np.zeros_like(inter), mat,
                            np.ones_like(inter), None, 1)
    return det, resp, ch


def _flat(value):
    """An isotropic intensity, flat in energy."""
    def f(e, z):
        return np.full(np.broadcast_shapes(e.shape, z.shape), value)
    return f


# -- the cosmic diffuse background ---------------------------------------------------------


def test_cxb_against_published_values():
    # Gruber et al. (1999) at 100 keV: E I = 0.2433 keV cm-2 s-1 sr-1 keV-1.  The HEAO-1 A4
    # MED measurement it joins (Kinzer et al. 1997, ApJ 475, 361: (2.62 +- 0.05)e-3
    # (E/100 keV)^-2.75 photons cm-2 s-1 sr-1 keV-1, 80-400 keV) is 7 % higher: the fit runs
    # through several data sets; 10 % allowed.
    i100 = float(cxb_intensity(100.0))
    assert i100 == pytest.approx(2.4326e-3, rel=1e-4)
    assert i100 / 2.62e-3 == pytest.approx(1.0, abs=0.10)
    # Kinzer's 80-400 keV photon flux against the fit's: within 10 %.
    kin = quad(lambda e: 2.62e-3 * (e / 100) ** -2.75, 80, 400)[0]
    ours = quad(lambda e: float(cxb_intensity(e)), 80, 400)[0]
    assert ours / kin == pytest.approx(1.0, abs=0.10)
    # The two branches join at 60 keV (0.5580 vs 0.5587 keV/keV: 0.13 %).
    lo = 7.877 * 60**-0.29 * math.exp(-60 / 41.13) / 60
    assert float(cxb_intensity(60.0)) == pytest.approx(lo, rel=1e-12)
    assert float(cxb_intensity(60.0 * (1 + 1e-9))) / lo == pytest.approx(1.0, abs=2e-3)
    # Boldt (1987) as quoted by HEASARC for Suzaku/PIN: 9.0e-9 (E/3)^-0.29 exp(-E/40)
    # erg cm-2 s-1 sr-1 keV-1; at 3 and 30 keV the fit is 5 % and 3 % lower.  6 % allowed.
    for e in (3.0, 30.0):
        boldt = 9.0e-9 * (e / 3) ** -0.29 * math.exp(-e / 40) / 1.602176634e-9 / e
        assert float(cxb_intensity(e)) / boldt == pytest.approx(1.0, abs=0.06)
    # COMPTEL (Kappadath 1998): 1.05e-4 photons cm-2 s-1 sr-1 MeV-1 at 5 MeV; Gruber's fit
    # (made on earlier COMPTEL points) is 41 % higher: checked only as < 1.5x.
    assert 1.0 < float(cxb_intensity(5000.0)) / 1.05e-7 < 1.5


# -- the atmospheric gamma rays ------------------------------------------------------------


def test_atmospheric_model_against_the_source_numbers():
    # Energy integrals given with the parameterisation (Mizuno et al. 2004 as coded in
    # Fermi-LAT CRflux): vertical downward 2.10e3 (30 keV-100 GeV) and 414.2 (> 1 MeV),
    # vertical upward 1.36e4 and 2378, photons m-2 s-1 sr-1.  Quoted to 3-4 digits: 0.2 %.
    def integral(z, lo):
        def f(ln):
            e = math.exp(ln)
            return float(atmospheric_continuum(e, z, MIZUNO_DEPTH)) * e * 1e4
        pts = [math.log(v) for v in (1e3, 1e6) if v > lo]
        return quad(f, math.log(lo), math.log(1e8), points=pts, limit=400)[0]
    assert integral(0.0, 30.0) == pytest.approx(2.10e3, rel=2e-3)
    assert integral(0.0, 1000.0) == pytest.approx(414.2, rel=2e-3)
    assert integral(180.0, 30.0) == pytest.approx(1.36e4, rel=4e-3)
    assert integral(180.0, 1000.0) == pytest.approx(2378.0, rel=2e-3)
    # Solid-angle integrals of the angular shapes given there: 4.355 (0-60 deg), 12.617
    # (60-90), and relative to the nadir 4.868 (90-115), 3.955 (115-140), 1.471 (140-180);
    # 115 deg is 2.007 rad in the source, which moves the third by 0.1 %.
    def omega(f, a, b):
        return quad(lambda t: float(f(math.degrees(t))) * 2 * math.pi * math.sin(t),
                    math.radians(a), math.radians(b), limit=200)[0]
    assert omega(angular_shape_downward, 0, 60) == pytest.approx(4.355, rel=5e-4)
    assert omega(angular_shape_downward, 60, 90) == pytest.approx(12.617, rel=5e-4)
    assert omega(angular_shape_upward, 90, 115) == pytest.approx(4.868, rel=2e-3)
    assert omega(angular_shape_upward, 115, 140) == pytest.approx(3.955, rel=5e-4)
    assert omega(angular_shape_upward, 140, 180) == pytest.approx(1.471, rel=1e-3)
    # The shapes are continuous at their breaks (a transcription error would show).
    for f, z in ((angular_shape_downward, 60.0), (angular_shape_upward, math.degrees(2.007)),
                 (angular_shape_upward, math.degrees(2.443))):
        assert float(f(z - 1e-6)) == pytest.approx(float(f(z + 1e-6)), rel=1e-2)
    # Hemispheres: nothing downward from below, nothing upward from above.
    assert float(angular_shape_downward(120.0)) == 0.0
    assert float(angular_shape_upward(30.0)) == 0.0


def test_depth_dependence():
    # Downward continuum and line grow with depth (produced in the air above); the albedo
    # does not depend on it; the CXB reaching the balloon falls with depth.
    x = np.array([2.0, 4.0, 8.0, 16.0])
    down = atmospheric_continuum(200.0, 30.0, x)
    assert np.all(np.diff(down) > 0)
    assert down[2] / down[1] == pytest.approx(2.0, rel=1e-12)
    assert np.ptp(atmospheric_continuum(200.0, 150.0, x)) == 0.0
    assert np.all(np.diff(annihilation_line(0.0, x)) > 0)
    atm = _exp_atmosphere()
    bg = BalloonBackground(atm)
    t = bg.cxb(100.0, 30.0, np.array([40.0, 35.0, 30.0, 25.0]))
    assert np.all(np.diff(t) < 0)


def test_high_energy_downward_against_anand_1973():
    # Anand, Daniel & Stephens (1973, Pramana 1, 2): 129.4 E^-2.62 photons m-2 sr-1 s-1 GeV-1
    # at an effective depth of 14.3 g/cm2 (Hyderabad, 40-1000 GeV).  The model scaled to that
    # depth gives 0.74x at 40 GeV and 1.09x at 100 GeV (the indices differ, 2.20 vs 2.62);
    # within 1.5x tests the > 1 GeV branch and the linear depth scaling together.
    for g in (40.0, 100.0):
        ours = float(atmospheric_continuum(g * 1e6, 0.0, 14.3)) * 1e4 * 1e6
        assert 1 / 1.5 < ours / (129.4 * g**-2.62) < 1.5


def test_intensity_for_a_monte_carlo():
    atm = _exp_atmosphere()
    bg = BalloonBackground(atm, mask_opacity=0.25)
    e, h = 200.0, 33.0
    x = float(bg.depth(h))
    for z in (0.0, 45.0, 120.0, 170.0):
        expect = (float(cxb_intensity(e)) * float(atm.transmission(e, z, h))
                  + float(atmospheric_continuum(e, z, x)))
        expect *= 0.75 if z < 90 else 1.0
        assert float(bg.intensity(e, z, h)) == pytest.approx(expect, rel=1e-12)


def _exp_atmosphere(h_scale=6.9):
    h = np.linspace(0.0, 120.0, 481)
    return Atmosphere(h, 1.225e-3 * np.exp(-h / h_scale), radius=6371.0)


# -- folding -------------------------------------------------------------------------------


def test_black_cylinder_isotropic_closed_form():
    # A flat isotropic intensity I through a black cylinder from all 4 pi: the projected
    # area averaged over the sphere is (total surface) / 4, so r = pi S I dE,
    # S = 2 pi R^2 + 2 pi R H.  From one side only through a thin disc: pi^2 R^2 I dE.
    R, H = 2.5, 5.0
    det, resp, ch = _black(R, H)
    flat = _flat(1e-3)
    r = diffuse_rates(flat, resp, det)
    de = np.diff(ch)
    S = 2 * math.pi * R * R + 2 * math.pi * R * H
    # The quadrature is 16-point Gauss-Legendre on 6 pieces of a smooth integrand: 1e-9.
    np.testing.assert_allclose(r, math.pi * S * 1e-3 * de, rtol=1e-9)
    det0, resp0, ch0 = _black(R, 1e-9)
    r0 = diffuse_rates(flat, resp0, det0, upward=False)
    np.testing.assert_allclose(r0, math.pi**2 * R * R * 1e-3 * np.diff(ch0), rtol=1e-6)
    # The mask's mean opacity scales the downward half only.
    half = diffuse_rates(flat, resp, det, downward_factor=0.5)
    np.testing.assert_allclose(half, 0.75 * r, rtol=1e-9)


def test_conservation_and_response_angles():
    # Counts summed over channels = interactions x the redistribution's row sums (here
    # 0.9, 0.7, 0.5: the rest leaves no deposit).
    R, H = 2.5, 5.0
    rows = np.array([0.9, 0.7, 0.5])
    det, resp, ch = _black(R, H, rows=rows)
    flat = _flat(2e-3)
    r = diffuse_rates(flat, resp, det)
    S = 2 * math.pi * R * R + 2 * math.pi * R * H
    np.testing.assert_allclose(r, math.pi * S * 2e-3 * np.diff(ch) * rows, rtol=1e-9)
    # A response tabulated only to 80 deg: q and M held beyond, exact for a black detector.
    det2, resp2, _ = _black(R, H, angles=[0.0, 30.0, 60.0, 80.0])
    np.testing.assert_allclose(diffuse_rates(flat, resp2, det2),
                               math.pi * S * 2e-3 * np.diff(ch), rtol=1e-9)


def test_fold_against_independent_quadrature():
    # The CXB through the air and the atmospheric continuum at 33 km, folded through a black
    # cylinder, against Simpson's rule on a fine grid (2001 angles per piece between the
    # shapes' breaks, 401 energies in ln E) of int dE int dOmega I(E, z) A(theta) over one
    # true-energy bin.  Simpson's error here is < 1e-7; the fixed Gauss-Legendre rule of the
    # fold must hold 1e-4 despite the steep transmission near the horizon.
    R, H = 2.5, 5.0
    det, resp, ch = _black(R, H, energies=(80.0, 100.0, 125.0))
    atm = _exp_atmosphere()
    bg = BalloonBackground(atm)
    comp = bg.components(resp, det, 33.0)
    x = float(bg.depth(33.0))
    ln_e = np.linspace(math.log(ch[1]), math.log(ch[2]), 401)
    e = np.exp(ln_e)[:, None]
    pieces = np.radians([0, 60, 90, 115, 140, 180])
    for key in ("cxb", "continuum"):
        total = 0.0
        for a, b in itertools.pairwise(pieces):
            z = np.linspace(a, b, 2001)[None, :]
            t = np.where(z < math.pi / 2, z, math.pi - z)
            area = math.pi * R * R * np.cos(t) + 2 * R * H * np.sin(t)
            if key == "cxb":
                inten = cxb_intensity(e) * atm.transmission(e, np.degrees(z), 33.0)
            else:
                inten = atmospheric_continuum(e, np.degrees(z), x)
            f = inten * area * 2 * math.pi * np.sin(z) * e  # d(ln E)
            total += simpson(simpson(f, x=z[0], axis=1), x=ln_e)
        assert comp[key][1] == pytest.approx(total, rel=1e-4)


def test_mask_transmission():
    # Opaque slats a = 1, b = 1, h = 2 cm: b/(a+b) at the zenith; against a brute-force
    # average over azimuth of max(0, b - h tan z |cos phi|) / (a+b) (1e5 azimuths: 1e-6);
    # a thin mask is its open fraction at every angle; it closes toward the horizon.
    mask = Mask(1.0, 1.0, 2.0, 50.0, mu=np.inf)
    z = np.array([0.0, 10.0, 26.565, 45.0, 70.0, 89.0])
    t = mask_transmission(mask, z)
    assert t[0] == pytest.approx(0.5, rel=1e-12)
    phi = np.linspace(0.0, 2 * math.pi, 100_001)[:-1]
    for zi, ti in zip(z, t, strict=True):
        c = 2.0 * math.tan(math.radians(zi))
        brute = np.mean(np.maximum(0.0, 1.0 - c * np.abs(np.cos(phi)))) / 2.0
        assert ti == pytest.approx(brute, abs=1e-6)
    assert np.all(np.diff(t) < 0)
    assert float(mask_transmission(mask, 120.0)) == 0.0
    thin = Mask(1.0, 3.0, 1e-12, 50.0, mu=np.inf)
    np.testing.assert_allclose(mask_transmission(thin, z), 0.75, rtol=1e-9)
    # A non-uniform pattern: two gaps of 0.5 cm per period behave as two narrow gaps.
    split = Mask(1.0, 1.0, 2.0, 50.0, mu=np.inf, slat_edges=[0.25, 0.75, 1.25, 1.75])
    c = 2.0 * math.tan(math.radians(10.0))
    brute = 2 * np.mean(np.maximum(0.0, 0.5 - c * np.abs(np.cos(phi)))) / 2.0
    assert float(mask_transmission(split, 10.0)) == pytest.approx(brute, abs=1e-6)
    # In the background: the downward half scaled direction by direction.
    det, resp, _ = _black()
    flat = _flat(1e-3)
    full = diffuse_rates(flat, resp, det, upward=False)
    masked = diffuse_rates(flat, resp, det, upward=False,
                           downward_factor=lambda th: mask_transmission(mask, np.degrees(th)))
    assert np.all(masked < 0.5 * full) and np.all(masked > 0)
    bg = BalloonBackground(_exp_atmosphere(), mask=mask)
    assert float(bg.intensity(200.0, 30.0, 33.0)) == pytest.approx(
        float(BalloonBackground(_exp_atmosphere()).intensity(200.0, 30.0, 33.0))
        * float(mask_transmission(mask, 30.0)), rel=1e-12)


def test_line_is_shared_exactly():
    # A narrow line at a node energy lands in its bin; its counts are the angular integral
    # of the line intensity times the projected area (closed form for a flat intensity).
    R, H = 2.5, 5.0
    det, resp, _ = _black(R, H, energies=(300.0, 511.0, 900.0))
    def flat(e, z):
        return np.ones(z.shape) * 1e-2
    r = diffuse_rates(flat, resp, det, line=(511.0, 1.0))
    S = 2 * math.pi * R * R + 2 * math.pi * R * H
    np.testing.assert_allclose(r, [0.0, math.pi * S * 1e-2, 0.0], atol=1e-12)


def test_balloon_background_components_and_flight():
    atm = _exp_atmosphere()
    det, resp, ch = _black(2.5, 5.0, energies=np.geomspace(40.0, 3000.0, 24))
    bg = BalloonBackground(atm)
    comp = bg.components(resp, det, 35.0)
    assert set(comp) == {"cxb", "continuum", "line"}
    assert all(np.all(v >= 0) for v in comp.values())
    # The line lands only in the bin holding 511 keV.
    k = int(np.searchsorted(ch, 511.0)) - 1
    assert comp["line"][k] > 0 and comp["line"].sum() == pytest.approx(comp["line"][k])
    # Deeper: more atmospheric continuum, less CXB; rates interpolate along a flight.
    deep = bg.components(resp, det, 30.0)
    assert deep["continuum"].sum() > comp["continuum"].sum()
    assert deep["cxb"].sum() < comp["cxb"].sum()
    flight = bg.flight_rates(resp, det, [30.0, 32.5, 35.0], step=0.5)
    np.testing.assert_allclose(flight[0], bg.rates(resp, det, 30.0), rtol=1e-12)
    np.testing.assert_allclose(flight[2], bg.rates(resp, det, 35.0), rtol=1e-12)
    # Each component along the flight (the fit's templates) is that component at the grid's
    # altitudes, and midway between two grid altitudes the mean of the two (linear).
    parts = bg.flight_components(resp, det, [30.0, 30.25, 32.5, 35.0], step=0.5)
    for k in comp:
        np.testing.assert_allclose(parts[k][3], comp[k], rtol=1e-12)
        np.testing.assert_allclose(parts[k][0], deep[k], rtol=1e-12)
        np.testing.assert_allclose(parts[k][1], 0.5 * (deep[k] + bg.components(
            resp, det, 30.5)[k]), rtol=1e-12)
    # flight_rates sums the interpolated components; interpolating the summed rates (as it
    # did before the components) is the same linear map applied in the other order, so the
    # two agree to rounding (measured 3e-16 relative; 1e-13 allows a few ulps per term).
    summed = bg.flight_rates(resp, det, [30.0, 30.1, 30.25, 32.5, 35.0], step=0.5)
    tab = {h: bg.rates(resp, det, h) for h in (30.0, 30.5, 32.5, 35.0)}
    old = [tab[30.0], 0.8 * tab[30.0] + 0.2 * tab[30.5], 0.5 * (tab[30.0] + tab[30.5]),
           tab[32.5], tab[35.0]]
    np.testing.assert_allclose(summed, old, rtol=1e-13)
    # A mask stopping everything from above leaves the albedo and the CXB's (zero) share
    # from below.
    shut = BalloonBackground(atm, mask_opacity=1.0).components(resp, det, 35.0)
    assert shut["cxb"].sum() < 1e-6 * comp["cxb"].sum()
    assert 0 < shut["continuum"].sum() < comp["continuum"].sum()


def test_fit_normalisations_recovers_scales():
    # Poisson counts from known scales of three templates: the fit recovers them within
    # 4 of its own standard deviations (estimated by repeating, 40 realisations).
    rng = np.random.default_rng(7)
    ch = np.linspace(30.0, 2000.0, 41)
    t1 = internal_rates(PowerLaw(K=0.05, index=-1.5, piv=100.0), ch)
    t2 = internal_rates(Gaussian(F=0.5, mu=511.0, sigma=20.0), ch)
    t3 = internal_rates(PowerLaw(K=0.02, index=-0.5, piv=100.0), ch)
    truth = np.array([1.3, 0.7, 2.0])
    mu = 1000.0 * (truth @ np.array([t1, t2, t3]))
    fits = np.array([list(fit_normalisations(rng.poisson(mu), 1000.0,
                                             {"a": t1, "b": t2, "c": t3}).values())
                     for _ in range(40)])
    mean, sd = fits.mean(axis=0), fits.std(axis=0, ddof=1)
    assert np.all(np.abs(mean - truth) < 4 * sd / math.sqrt(40) + 1e-3)
    # Exact expectations give the truth (the maximum of the likelihood).
    exact = fit_normalisations(mu, 1000.0, {"a": t1, "b": t2, "c": t3})
    np.testing.assert_allclose(list(exact.values()), truth, rtol=1e-4)


def test_bad_input():
    det, resp, _ = _black()
    flat = _flat(1.0)
    with pytest.raises(ParameterError, match="energy"):
        cxb_intensity(1.0)
    with pytest.raises(ParameterError, match="energy"):
        atmospheric_continuum(10.0, 0.0, 4.0)
    with pytest.raises(ParameterError, match="zenith"):
        atmospheric_continuum(100.0, 190.0, 4.0)
    with pytest.raises(ParameterError, match="depth"):
        atmospheric_continuum(100.0, 0.0, 50.0)
    with pytest.raises(ParameterError, match="depth"):
        annihilation_line(0.0, -1.0)
    with pytest.raises(ParameterError, match="downward_factor"):
        diffuse_rates(flat, resp, det, downward_factor=1.5)
    with pytest.raises(ParameterError, match="response"):
        diffuse_rates(flat, "resp", det)
    with pytest.raises(ParameterError, match="detectors"):
        diffuse_rates(flat, resp, None)
    with pytest.raises(ParameterError, match="mask_opacity"):
        BalloonBackground(_exp_atmosphere(), mask_opacity=2.0)
    with pytest.raises(ParameterError, match="atmosphere"):
        BalloonBackground("air")
    with pytest.raises(ParameterError, match="mask"):
        BalloonBackground(_exp_atmosphere(), mask="lead")
    with pytest.raises(ParameterError, match="mask"):
        mask_transmission(None, 10.0)
    with pytest.raises(ParameterError, match="channel_edges"):
        internal_rates(PowerLaw(), [100.0, 50.0])
    with pytest.raises(ParameterError, match="templates"):
        fit_normalisations([1.0, 2.0], 10.0, {"a": [1.0, 2.0, 3.0]})
    with pytest.raises(ParameterError, match="exposure"):
        fit_normalisations([1.0, 2.0], 0.0, {"a": [1.0, 2.0]})
