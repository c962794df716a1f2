"""Calibration of the statistical claims of :mod:`rotmod.sources` (issue 21).

Measured on the survey instrument of the issue -- 37 detectors of 5 cm (hexagonal, 3 rings)
under 3/3/3 cm lead slats 1 m up, rotation period 60 s, 300 keV, the exact model, a 20 x 20
deg field of 0.5 deg pixels, 180 mask-angle bins of 1000 s exposure each and a flat
background of 2 counts/s per detector that the fit does not know (fitted per detector):

1. ``null``: TS of a test source at a fixed, pre-chosen position (4, 120) deg on
   background-only data against ``1/2 chi2_0 + 1/2 chi2_1`` (fraction at 0, KS test of the
   TS > 0 part against chi2_1, tail fractions); a subset cross-checked with :func:`fit`;
2. ``mapmax``: the maximum of the 1600-pixel TS map on empty fields; thresholds for 1 % and
   0.1 % false detections per map (empirical quantiles), the effective number of independent
   trials ``N_eff`` of ``P(max < t) = F(t)^N_eff`` (``F`` the mixture's CDF) -- which grows
   with ``t`` -- and the Euler-characteristic (Gaussian kinematic formula) fit whose area
   term scales the thresholds to other field sizes;
3. ``coverage``: single sources injected at random positions (theta 1-8 deg, uniform in
   solid angle) with expected ``SNR = sqrt(TS)`` 6-50; fitted from the TS-map peak with a
   free position (:func:`fit`), :func:`localise` with ``systematic=0``; how often the truth
   lies in the 68 % / 90 % regions; then the truth shifted by a Gaussian "attitude error" of
   ``SIGMA_SYS`` per axis and regions with ``systematic=SIGMA_SYS``;
4. ``ul``: 95 % upper limits at the known position for faint sources (expected TS 0-16) --
   how often the limit is at or above the true flux;
5. ``mc``: a few sources simulated photon by photon (:func:`rotmod.montecarlo.simulate_observation`
   of :meth:`SkyModel.point_sources`, folded with :func:`rotmod.events.fold`) beside Poisson
   draws of the exact model (:meth:`SkyModel.simulate`, what parts 1-4 use): the two agree;
6. ``r90`` vs SNR against the Swift-BAT coded-mask law rescaled to the RM's scale ``b / L``
   (figure ``docs/figures/sources_r90.png``).

Every injection of parts 1-4 is a Poisson draw of the exact model's expected counts
(:meth:`SkyModel.simulate`), with fixed seeds.  Raw results go to
``benchmarks/results/sources_calibration.npz`` (and a JSON summary); ``--report`` prints the
tables and redraws the figure from them.  The numbers are recorded in ``docs/sources.md``.

    python benchmarks/sources_calibration.py            # full run (35-60 min on 2 shared cores)
    python benchmarks/sources_calibration.py --quick    # smoke run (2-5 min)
    python benchmarks/sources_calibration.py --report   # tables + figure from the saved run
    python benchmarks/sources_calibration.py --parts mapmax   # rerun parts, keep the others
"""

from __future__ import annotations

import os

# The fits' linear algebra is on small matrices (6660 bins x 38 amplitudes): on a shared
# 2-core machine threaded OpenBLAS made fit_positions 10-40x slower (measured 27 s vs 0.7 s
# for one fit), so BLAS runs on one thread here (numba kernels keep their threads).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse
import json
import platform
import sys
import time
from itertools import pairwise
from pathlib import Path

import numba
import numpy as np
from scipy.optimize import minimize_scalar
from scipy.stats import binom, chi2, kstest

from rotmod import DetectorArray, Instrument, Mask
from rotmod.events import fold
from rotmod.montecarlo import simulate_observation
from rotmod.reconstruction.data import PoissonData
from rotmod.response import build_response
from rotmod.response.columns import columns_at
from rotmod.sky import SkyGrid
from rotmod.sources import PointSource, SkyModel, SourceFitter, fit, localise
from rotmod.sources.detection import pixel_position
from rotmod.sources.fitting import geometric_scale
from rotmod.sources.model import tangent_basis
from rotmod.sources.tsmap import null_state, scan_test_source

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
FIGURE = ROOT / "docs" / "figures" / "sources_r90.png"

SEED = 20260021          # every realisation's seed is derived from (SEED, part, index)
ENERGY = 300.0           # keV
EXPOSURE = 1000.0        # s per detector and mask-angle bin
BACKGROUND = 2.0         # counts/s per detector, flat; unknown to the fit
N_TIME = 180
FIXED_POSITION = (4.0, 120.0)  # the pre-chosen test position of part 1 (deg)
THETA_RANGE = (1.0, 8.0)       # injections (deg): well inside the 20 x 20 deg field
SNR_RANGE = (6.0, 50.0)        # expected sqrt(TS) of the coverage injections
UL_SNR_MAX = 4.0               # expected sqrt(TS) of the upper-limit injections
UL_ZERO_FRACTION = 0.1         # of them with true flux 0
SIGMA_SYS = 0.1                # deg per axis: the "attitude error" of part 3
UL_CONFIDENCE = 0.95
Q_UL = float(chi2.ppf(2 * UL_CONFIDENCE - 1, 1))  # 2.706
# (theta, phi, expected SNR) of the Monte Carlo checks.
MC_CASES = [(2.5, 40.0, 8.0), (5.0, 160.0, 15.0), (6.5, 260.0, 30.0), (4.0, 330.0, 50.0)]
MC_BRIGHT = 0.5  # flux of the source-only Monte Carlo runs (~1.5e6 photons in 180 000 s)
BAT_R90_ARCMIN, BAT_SCALE_ARCMIN, BAT_SLOPE = 10.9, 17.0, -0.7
COVERAGE_BINS = [0.0, 10.0, 17.0, 30.0, np.inf]   # expected SNR
UL_BINS = [0.0, 1.0, 2.0, 3.0, np.inf]            # expected SNR (flux 0 counted apart)
Z = 2.0  # the "2 sigma" of the binomial intervals


def rng_for(part: int, i: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([SEED, part, i]))


def say(msg: str) -> None:
    print(msg, flush=True)


# ----------------------------------------------------------------------------- statistics
def wilson(k: float, n: float, z: float = Z) -> tuple[float, float]:
    """Wilson score interval of a binomial fraction (``z`` sigma)."""
    if n <= 0:
        return float("nan"), float("nan")
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return float(max(mid - half, 0.0)), float(min(mid + half, 1.0))


def fraction(k: float, n: float) -> str:
    if n <= 0:
        return "--"
    lo, hi = wilson(k, n)
    return f"{int(k)}/{int(n)} = {k / n:.3f} [{lo:.3f}, {hi:.3f}]"


def mix_cdf(t):
    """CDF of ``1/2 chi2_0 + 1/2 chi2_1`` at ``t >= 0``."""
    return 0.5 + 0.5 * chi2.cdf(t, 1)


def mix_sf(t):
    return 0.5 * chi2.sf(t, 1)


def threshold_for(alpha: float, n_eff: float) -> float:
    """TS whose exceedance by the maximum of ``n_eff`` independent mixtures is ``alpha``."""
    p = -np.expm1(np.log1p(-alpha) / n_eff)  # per-trial p = 1 - (1 - alpha)^(1/N)
    return float(chi2.isf(2 * p, 1))


def n_eff_mle(maxima: np.ndarray) -> tuple[float, float]:
    """ML estimate of ``N`` in ``P(max < t) = F(t)^N`` from every map, and its error."""
    n = maxima.size
    big_n = -n / float(np.sum(np.log(mix_cdf(maxima))))
    return big_n, big_n / np.sqrt(n)


def n_eff_tail(maxima: np.ndarray, t0: float) -> float:
    """ML estimate of ``N`` from the maxima above ``t0`` only (the upper tail's shape)."""
    tail = maxima[maxima > t0]
    log_f = np.log(mix_cdf(tail))
    log_dens = np.log(0.5 * chi2.pdf(tail, 1))
    log_f0 = float(np.log(mix_cdf(t0)))

    def nll(log_n: float) -> float:
        big_n = np.exp(log_n)
        ll = np.sum(log_n + (big_n - 1) * log_f + log_dens)
        return -(ll - tail.size * np.log(-np.expm1(big_n * log_f0)))

    return float(np.exp(minimize_scalar(nll, bounds=(0.0, 12.0), method="bounded").x))


def n_eff_at(p_above: float, t: float) -> float:
    """``N`` with ``1 - F(t)^N = p_above``: the independent trials a measured rate implies."""
    return float(np.log1p(-p_above) / np.log(mix_cdf(t))) if p_above < 1 else np.inf


#: TS above which the Euler-characteristic formula is fitted: where E[EC] ~ P(max > u), i.e.
#: where the L2 that each measured exceedance implies stops growing (5000 maps: 264, 365, 413,
#: 434, 409 at TS 9, 12, 14, 16, 18).  Starting at 12-16 moves the thresholds by < 0.4.
EC_FIT_FROM = 14.0


def ec_sf(u, l1: float, l2: float):
    """Expected Euler characteristic of ``{TS > u}`` for a 2-D field whose signed root
    ``z`` (TS = max(z, 0)^2) is a unit Gaussian field (Adler & Taylor's Gaussian kinematic
    formula; ~ P(max TS > u) in the tail).  ``l1``, ``l2``: the field's Lipschitz-Killing
    curvatures (half its boundary length and its area, in units of the correlation length);
    the Euler characteristic of the field itself is 1."""
    u = np.asarray(u, float)
    c = np.sqrt(u)
    e = np.exp(-u / 2)
    return chi2.sf(u, 1) / 2 + l1 * e / (2 * np.pi) + l2 * c * e / (2 * np.pi) ** 1.5


def ec_pdf(u, l1: float, l2: float):
    """``-d ec_sf / du``."""
    u = np.asarray(u, float)
    c = np.sqrt(u)
    e = np.exp(-u / 2)
    return (chi2.pdf(u, 1) / 2 + l1 * e / (4 * np.pi)
            + l2 * e * (c / 2 - 1 / (2 * c)) / (2 * np.pi) ** 1.5)


def ec_fit(maxima: np.ndarray, u0: float) -> dict:
    """ML fit of the area term ``L2`` (``L1 = 0``: over this range of TS the boundary term
    is degenerate with it) to the maxima above ``u0``; those below count as one probability."""
    tail = maxima[maxima > u0]
    n_below = maxima.size - tail.size

    def nll(log_l2: float) -> float:
        l2 = np.exp(log_l2)
        return -(np.sum(np.log(ec_pdf(tail, 0.0, l2)))
                 + n_below * np.log1p(-float(ec_sf(u0, 0.0, l2))))

    best = minimize_scalar(nll, bounds=(0.0, 12.0), method="bounded",
                           options={"xatol": 1e-8})
    h = 0.02
    curv = (nll(best.x + h) - 2 * nll(best.x) + nll(best.x - h)) / h**2
    l2 = float(np.exp(best.x))
    return {"L1": 0.0, "L2": l2, "L2_err": float(l2 / np.sqrt(curv)), "u0": u0,
            "n_tail": int(tail.size)}


def l2_at(p_above: float, u: float) -> float:
    """The ``L2`` (with ``L1 = 0``) that makes ``ec_sf(u)`` equal a measured rate."""
    from scipy.optimize import brentq

    if not 0 < p_above < 1:
        return float("nan")
    return float(brentq(lambda l2: float(ec_sf(u, 0.0, l2)) - p_above, 0.0, 1e7))


def ec_threshold(alpha: float, l1: float, l2: float) -> float:
    """TS ``u`` with ``ec_sf(u) = alpha``."""
    from scipy.optimize import brentq

    return float(brentq(lambda u: float(ec_sf(u, l1, max(l2, 0.0))) - alpha, 1.0, 200.0))


def quantile_interval(x: np.ndarray, q: float) -> tuple[float, float, float]:
    """Empirical ``q`` quantile and its 2-sigma order-statistic interval (NaN beyond data)."""
    s = np.sort(x)
    n = s.size
    lo_rank = int(binom.ppf(0.02275, n, q))
    hi_rank = int(binom.ppf(0.97725, n, q))
    lo = s[lo_rank] if lo_rank < n else np.nan
    hi = s[hi_rank] if hi_rank < n else np.nan
    return float(np.quantile(x, q)), float(lo), float(hi)


def poisson_deviance(y: np.ndarray, mu: np.ndarray) -> float:
    """``2 sum y ln(y / mu) - (y - mu)``: ~ chi2 with one dof per bin when ``mu`` is true."""
    yl = np.where(y > 0, y * np.log(np.where(y > 0, y, 1.0) / mu), 0.0)
    return float(2.0 * np.sum(yl - (y - mu)))


# ----------------------------------------------------------------------------- setup
class Setup:
    """The response built once, the background-only model and its Asimov null."""

    def __init__(self) -> None:
        t = time.perf_counter()
        self.inst = Instrument(Mask(3, 3, 3, 100), DetectorArray.hexagonal(5, rings=3),
                               rotation_period=60)
        self.response = build_response(self.inst, SkyGrid.square(20, 0.5), N_TIME,
                                       energy=ENERGY, dtype=np.float64)
        self.build_s = time.perf_counter() - t
        r = self.response
        self.scale_deg = float(np.degrees(geometric_scale(r)))
        self.exposure = np.full((r.n_det, r.n_time), EXPOSURE)
        self.null = SkyModel(background=np.full(r.n_det, BACKGROUND))
        self.all_columns = r.block(n=(0, r.n_sky))
        # Asimov background-only data: each position's sensitivity (flux with median TS 25).
        self.asimov_null = SourceFitter(r, PoissonData(
            self.null.expected_counts(r, EXPOSURE), self.exposure))
        self.asimov_state = null_state(self.asimov_null, None)

    def simulate(self, model: SkyModel, rng: np.random.Generator) -> PoissonData:
        return model.simulate(self.response, EXPOSURE, seed=rng)

    def sensitivity(self, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
        cols = columns_at(self.response, (theta, phi))
        return scan_test_source(self.asimov_null, self.asimov_state,
                                self.asimov_null.on_bins(cols), Q_UL, 25.0)[:, 4]

    def asimov_ts(self, model: SkyModel) -> float:
        """Median TS of ``model``'s source: its Asimov data at the true position."""
        r = self.response
        f = SourceFitter(r, PoissonData(model.expected_counts(r, EXPOSURE), self.exposure))
        th, ph = model.sources[0].position
        cols = columns_at(r, (np.array([th]), np.array([ph])))
        return float(scan_test_source(f, null_state(f, None), f.on_bins(cols), 0.0, 0.0)[0, 0])

    def ts_map(self, fitter: SourceFitter) -> np.ndarray:
        """TS only (no limits) of a test source at every pixel against the background."""
        return scan_test_source(fitter, null_state(fitter, None),
                                fitter.on_bins(self.all_columns), 0.0, 0.0)[:, 0]


def random_positions(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Uniform in solid angle (small-angle: in the disc's area) for theta in THETA_RANGE."""
    t0, t1 = THETA_RANGE
    theta = np.sqrt(rng.uniform(t0**2, t1**2, n))
    return theta, rng.uniform(0.0, 360.0, n)


def progress(part: str, i: int, n: int, t0: float, every: int) -> None:
    if (i + 1) % every == 0 or i + 1 == n:
        el = time.perf_counter() - t0
        eta = el / (i + 1) * (n - i - 1)
        say(f"  [{part}] {i + 1}/{n}  {el:7.1f} s elapsed, ~{eta:6.0f} s to go, "
            f"load {os.getloadavg()[0]:.2f}")


# ----------------------------------------------------------------------------- parts
def part_null(s: Setup, counts: tuple[int, int]) -> dict:
    """TS at one fixed position on background-only data; ``fit`` on the first ``n_check``."""
    n, n_check = counts
    th, ph = FIXED_POSITION
    cols = columns_at(s.response, (np.array([th]), np.array([ph])))
    ts = np.empty(n)
    ts_fit = np.full(n_check, np.nan)
    t0 = time.perf_counter()
    for i in range(n):
        data = s.simulate(s.null, rng_for(1, i))
        f = SourceFitter(s.response, data)
        ts[i] = scan_test_source(f, null_state(f, None), f.on_bins(cols), 0.0, 0.0)[0, 0]
        if i < n_check:
            ts_fit[i] = fit(s.response, data, SkyModel([PointSource(FIXED_POSITION)])).ts[0]
        progress("null", i, n, t0, max(n // 10, 1))
    return {"ts": ts, "ts_fit": ts_fit, "seconds": time.perf_counter() - t0}


def part_mapmax(s: Setup, n: int) -> dict:
    """Maximum of the TS map (every pixel) on background-only data."""
    thresholds = np.array([1.0, 4.0, 9.0, 16.0, 25.0])
    maxima, argmax = np.empty(n), np.empty(n, np.int64)
    n_zero = np.empty(n, np.int64)
    n_above = np.empty((n, thresholds.size), np.int64)
    t0 = time.perf_counter()
    for i in range(n):
        f = SourceFitter(s.response, s.simulate(s.null, rng_for(2, i)))
        ts = s.ts_map(f)
        argmax[i] = int(np.nanargmax(ts))
        maxima[i] = ts[argmax[i]]
        n_zero[i] = np.count_nonzero(ts <= 0.0)
        n_above[i] = (ts[:, None] > thresholds[None, :]).sum(axis=0)
        progress("mapmax", i, n, t0, max(n // 20, 1))
    return {"max": maxima, "argmax": argmax, "n_zero": n_zero, "n_above": n_above,
            "thresholds": thresholds, "n_pixels": s.response.n_sky,
            "seconds": time.perf_counter() - t0}


def analyse(s: Setup, data, truth: PointSource, shift: np.ndarray | None = None) -> dict:
    """The pipeline on one data set: TS map -> peak -> fit (free position) -> regions.

    ``shift`` (rad, tangent plane of the truth) moves the "true" position for the
    systematic test: the regions with ``systematic=SIGMA_SYS`` should contain it.
    """
    r = s.response
    fitter = SourceFitter(r, data)
    t = time.perf_counter()
    ts_map = s.ts_map(fitter)
    peak = int(np.nanargmax(ts_map))
    start = PointSource(pixel_position(r, peak), free_position=True)
    res = fit(r, fitter.data, SkyModel([start]))
    src = res.model.sources[0]
    # TS at the true position against the same null: 2 delta ln L of the truth (Wilks).
    cols = columns_at(r, (np.array([truth.position[0]]), np.array([truth.position[1]])))
    ts_truth = float(scan_test_source(fitter, null_state(fitter, None), fitter.on_bins(cols),
                                      0.0, 0.0)[0, 0])
    t_fit = time.perf_counter() - t
    t = time.perf_counter()
    reg = localise(fitter, res.model, 0)
    t_loc = time.perf_counter() - t
    flux = src.flux
    lo, hi = res.flux_err[0]
    out = {
        "peak_pixel": peak, "peak_ts": float(ts_map[peak]),
        "peak_sep": PointSource(pixel_position(r, peak)).separation(truth),
        "fit_theta": src.position[0], "fit_phi": src.position[1],
        "fit_sep": src.separation(truth), "ts": float(res.ts[0]), "ts_truth": ts_truth,
        "flux_fit": flux, "flux_lo": flux - lo, "flux_hi": flux + hi,
        "in68": reg.contains(truth.position, 0.68), "in90": reg.contains(truth.position, 0.9),
        "r68": reg.radius(0.68), "r90": reg.radius(0.9), "area90": reg.area(0.9),
        "half_deg": float(np.degrees(reg.offsets[-1])), "closed": reg.closed,
        "n90": int(np.count_nonzero(reg.density >= reg.level(0.9))),
        "t_fit": t_fit, "t_localise": t_loc,
    }
    if shift is not None:
        v = truth.vector()
        e1, e2 = tangent_basis(v)
        moved = truth.at_vector(v + shift[0] * e1 + shift[1] * e2).position
        reg_s = localise(fitter, res.model, 0, systematic=SIGMA_SYS)
        out.update({"sys_dx": float(shift[0]), "sys_dy": float(shift[1]),
                    "sys_in68": reg_s.contains(moved, 0.68),
                    "sys_in90": reg_s.contains(moved, 0.9),
                    "sys_in68_without": reg.contains(moved, 0.68),
                    "sys_in90_without": reg.contains(moved, 0.9),
                    "sys_r90": reg_s.radius(0.9)})
    return out


def part_coverage(s: Setup, n: int) -> dict:
    rng = rng_for(3, 10**9)
    theta, phi = random_positions(rng, n)
    snr_target = np.exp(rng.uniform(*np.log(SNR_RANGE), n))
    sens = s.sensitivity(theta, phi)
    # Background-dominated: TS grows as flux^2, so flux = s25 * SNR / 5 lands near the
    # target; the expected SNR actually used below is the Asimov one at that flux.
    flux = sens * snr_target / 5.0
    rows = []
    t0 = time.perf_counter()
    for i in range(n):
        truth = PointSource((theta[i], phi[i]), flux=flux[i])
        model = s.null.replace(sources=(truth,))
        r_i = rng_for(3, i)
        data = s.simulate(model, r_i)
        shift = np.radians(SIGMA_SYS) * r_i.standard_normal(2)
        row = {"theta": theta[i], "phi": phi[i], "flux": flux[i], "snr_target": snr_target[i],
               "ts_asimov": s.asimov_ts(model)}
        row.update(analyse(s, data, truth, shift))
        rows.append(row)
        progress("coverage", i, n, t0, max(n // 40, 1))
    out = {k: np.array([row[k] for row in rows]) for k in rows[0]}
    out["seconds"] = time.perf_counter() - t0
    return out


def part_ul(s: Setup, counts: tuple[int, int]) -> dict:
    n, n_check = counts
    rng = rng_for(4, 10**9)
    theta, phi = random_positions(rng, n)
    snr_target = rng.uniform(0.0, UL_SNR_MAX, n)
    snr_target[rng.random(n) < UL_ZERO_FRACTION] = 0.0
    flux = s.sensitivity(theta, phi) * snr_target / 5.0
    cols = columns_at(s.response, (theta, phi))
    ts, f_hat, ul = np.empty(n), np.empty(n), np.empty(n)
    ts_asimov = np.empty(n)
    ul_fit = np.full(n_check, np.nan)
    t0 = time.perf_counter()
    for i in range(n):
        truth = PointSource((theta[i], phi[i]), flux=flux[i])
        model = s.null.replace(sources=(truth,))
        data = s.simulate(model, rng_for(4, i))
        f = SourceFitter(s.response, data)
        ts[i], f_hat[i], _, ul[i], _ = scan_test_source(f, null_state(f, None),
                                                        f.on_bins(cols[:, :, i:i + 1]),
                                                        Q_UL, 0.0)[0]
        ts_asimov[i] = s.asimov_ts(model) if flux[i] > 0 else 0.0
        if i < n_check:
            ul_fit[i] = fit(s.response, data, SkyModel([PointSource(truth.position)]),
                            ul_confidence=UL_CONFIDENCE).flux_ul[0]
        progress("ul", i, n, t0, max(n // 10, 1))
    return {"theta": theta, "phi": phi, "flux": flux, "snr_target": snr_target,
            "ts_asimov": ts_asimov, "ts": ts, "flux_fit": f_hat, "ul": ul, "ul_fit": ul_fit,
            "seconds": time.perf_counter() - t0}


def part_mc(s: Setup, n: int) -> dict:
    """Monte Carlo events beside Poisson draws of the exact model, same truth."""
    r = s.response
    th = np.array([c[0] for c in MC_CASES[:n]])
    ph = np.array([c[1] for c in MC_CASES[:n]])
    flux = s.sensitivity(th, ph) * np.array([c[2] for c in MC_CASES[:n]]) / 5.0
    rows = []
    t0 = time.perf_counter()
    for i in range(n):
        truth = PointSource((th[i], ph[i]), flux=flux[i])
        model = s.null.replace(sources=(truth,))
        t = time.perf_counter()
        events = simulate_observation(s.inst, model.point_sources(ENERGY),
                                      t_stop=EXPOSURE * r.n_time, background=model.background,
                                      seed=np.random.SeedSequence([SEED, 5, i]))
        folded = fold(events, r.time_bins)
        src_only = fold(events.select(events.source >= 0), r.time_bins)
        t_mc = time.perf_counter() - t
        expo = np.broadcast_to(np.asarray(folded.exposure, float), (r.n_det, r.n_time))
        mu = model.expected_counts(r, expo)
        mu_src = model.replace(background=np.zeros(r.n_det)).expected_counts(r, expo)
        sim = s.simulate(model, rng_for(5, i))
        row = {"theta": th[i], "phi": ph[i], "flux": flux[i], "ts_asimov": s.asimov_ts(model),
               "t_mc": t_mc, "n_events": len(events),
               "expected_events": float(mu.sum()),
               "source_events": int(src_only.counts.sum()),
               "expected_source_events": float(mu_src.sum()),
               "dev_mc": poisson_deviance(folded.counts.astype(float), mu),
               "dev_mc_source": poisson_deviance(src_only.counts.astype(float), mu_src),
               "dev_sim": poisson_deviance(sim.counts, mu)}
        for tag, data in (("mc", folded), ("sim", sim)):
            a = analyse(s, data, truth)
            for k in ("ts", "fit_sep", "r90", "in68", "in90", "flux_fit"):
                row[f"{tag}_{k}"] = a[k]
        # A finer look at the model itself: a bright source alone (flux MC_BRIGHT, ~1.5e6
        # photons), twice: total counts and deviance against the exact expectation.
        bright = SkyModel([PointSource(truth.position, flux=MC_BRIGHT)])
        mu_b = None
        for j in range(2):
            ev = simulate_observation(s.inst, bright.point_sources(ENERGY),
                                      t_stop=EXPOSURE * r.n_time,
                                      seed=np.random.SeedSequence([SEED, 6, i, j]))
            fb = fold(ev, r.time_bins)
            if mu_b is None:
                mu_b = bright.expected_counts(r, np.broadcast_to(
                    np.asarray(fb.exposure, float), (r.n_det, r.n_time)))
            row[f"bright_events_{j}"] = int(fb.counts.sum())
            row[f"bright_dev_{j}"] = poisson_deviance(fb.counts.astype(float), mu_b)
        row["bright_expected"] = float(mu_b.sum())
        rows.append(row)
        say(f"  [mc] {i + 1}/{n}  {time.perf_counter() - t0:7.1f} s elapsed")
    out = {k: np.array([row[k] for row in rows]) for k in rows[0]}
    out["n_bins"] = r.n_det * r.n_time
    out["seconds"] = time.perf_counter() - t0
    return out


# ----------------------------------------------------------------------------- report
def r90_law(snr: np.ndarray, r90_scaled: np.ndarray) -> dict:
    """Least-squares power law ``log r90/scale = log A + slope log SNR`` (and slope -0.7)."""
    x, y = np.log10(snr), np.log10(r90_scaled)
    (slope, log_a), cov = np.polyfit(x, y, 1, cov=True)
    a_fixed = 10 ** float(np.mean(y - BAT_SLOPE * x))
    return {"A": float(10**log_a), "slope": float(slope),
            "slope_err": float(np.sqrt(cov[0, 0])), "A_at_bat_slope": a_fixed,
            "bat_A": BAT_R90_ARCMIN / BAT_SCALE_ARCMIN, "bat_slope": BAT_SLOPE,
            "rms_dex": float(np.std(y - (log_a + slope * x)))}


def bin_label(lo: float, hi: float) -> str:
    if (lo, hi) == (0.0, np.inf):
        return "all"
    if lo == 0:
        return f"< {hi:g}"
    return f">= {lo:g}" if hi == np.inf else f"{lo:g}-{hi:g}"


def bat_r90_scaled(snr):
    return BAT_R90_ARCMIN / BAT_SCALE_ARCMIN * np.asarray(snr, float) ** BAT_SLOPE


def make_figure(cov: dict, law: dict, scale_deg: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    snr = np.sqrt(cov["ts"])
    y = cov["r90"] / scale_deg
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    hit = cov["in90"].astype(bool)
    ax.loglog(snr[hit], y[hit], ".", color="C0", ms=4, alpha=0.7,
              label="injected source, truth inside the 90 % region")
    ax.loglog(snr[~hit], y[~hit], "x", color="C3", ms=5,
              label="truth outside the 90 % region")
    xs = np.geomspace(max(snr.min(), 3.0), snr.max() * 1.1, 100)
    ax.loglog(xs, law["A"] * xs ** law["slope"], "-", color="C0",
              label=f"RM fit: {law['A']:.2f} SNR$^{{{law['slope']:.2f}}}$")
    ax.loglog(xs, bat_r90_scaled(xs), "--", color="k",
              label="Swift-BAT: (10.9'/17') SNR$^{-0.7}$")
    ax.set_xlabel("SNR = sqrt(TS) of the fitted source")
    ax.set_ylabel(f"r90 / (b/L),  b/L = {scale_deg:.2f} deg")
    sec = ax.secondary_yaxis("right", functions=(lambda v: v * scale_deg * 60,
                                                  lambda v: v / scale_deg / 60))
    sec.set_ylabel("r90 (arcmin)")
    from matplotlib.ticker import FormatStrFormatter, NullFormatter

    ax.set_xticks([4, 6, 10, 20, 30, 50])
    ax.set_yticks([0.02, 0.05, 0.1, 0.2])
    sec.set_yticks([1, 2, 5, 10, 20])
    for axis in (ax.xaxis, ax.yaxis, sec.yaxis):
        axis.set_major_formatter(FormatStrFormatter("%g"))
        axis.set_minor_formatter(NullFormatter())
    ax.set_title("Localisation of the survey RM (37 x 5 cm, 3/3/3 cm Pb at 1 m, 300 keV)",
                 fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def summarise(res: dict, meta: dict, figure: Path | None) -> dict:
    summary: dict = {"meta": meta}
    runs = meta.get("runs") or [{"parts": list(res), "load_start": meta.get("load_start"),
                                 "load_end": meta.get("load_end"),
                                 "seconds": meta.get("total_s")}]
    print(f"\nmachine: {meta['machine']}, {meta['cores']} cores, numba {meta['numba']} "
          f"({meta['numba_threads']} threads), numpy {meta['numpy']}, BLAS threads "
          f"{meta['blas_threads']}; response built in {meta['build_s']:.1f} s")
    for r in runs:
        print(f"run of {','.join(r['parts'])}: {r.get('seconds') or float('nan'):.0f} s, load "
              f"average {r.get('load_start') or float('nan'):.2f} at start, "
              f"{r.get('load_end') or float('nan'):.2f} at end")
    print("seconds per part: " + ", ".join(f"{k} {float(v['seconds']):.0f}"
                                           for k, v in res.items()))
    if "null" in res:
        p = res["null"]
        ts = p["ts"]
        n = ts.size
        zero = ts <= 1e-9
        pos = ts[~zero]
        ks = kstest(pos, chi2(1).cdf)
        print(f"\n### 1. TS at a fixed position {FIXED_POSITION} deg, {n} background-only "
              f"realisations ({p['seconds']:.0f} s)\n")
        print("| quantity | measured (2-sigma binomial) | 1/2 chi2_0 + 1/2 chi2_1 |")
        print("|---|---|---:|")
        print(f"| P(TS = 0) | {fraction(zero.sum(), n)} | 0.500 |")
        tails = {}
        for t in (1.0, 4.0, 9.0, 16.0):
            k = int(np.count_nonzero(ts > t))
            tails[t] = k / n
            print(f"| P(TS > {t:g}) | {fraction(k, n)} | {mix_sf(t):.4f} |")
        print(f"| KS test of TS > 0 against chi2_1 ({pos.size} values) | D = {ks.statistic:.4f},"
              f" p = {ks.pvalue:.3f} | |")
        ok = np.isfinite(p["ts_fit"])
        dts = float(np.max(np.abs(p["ts_fit"][ok] - ts[:ok.sum()]))) if ok.any() else np.nan
        print(f"\nfit() with the source fixed at the same position on the first {ok.sum()} "
              f"data sets: max |TS_fit - TS_scan| = {dts:.2e}")
        summary["null"] = {"n": n, "zero": int(zero.sum()), "ks_D": float(ks.statistic),
                           "ks_p": float(ks.pvalue), "tails": tails,
                           "max_abs_dts_fit": dts}
    if "mapmax" in res:
        p = res["mapmax"]
        mx = p["max"]
        n = mx.size
        n_pix = int(p["n_pixels"])
        n_eff, n_eff_err = n_eff_mle(mx)
        t_med = float(np.median(mx))
        n_tail = n_eff_tail(mx, t_med)
        ks = kstest(mx, lambda t: mix_cdf(t) ** n_eff)
        ec = ec_fit(mx, EC_FIT_FROM)
        print(f"\n### 2. Maximum of the TS map ({n_pix} pixels of 0.5 deg, 20 x 20 deg), {n} "
              f"empty fields ({p['seconds']:.0f} s)\n")
        print(f"max TS: median {t_med:.2f}, mean {mx.mean():.2f}, largest {mx.max():.2f}.  "
              f"Constant N_eff in P(max < t) = F(t)^N_eff: ML on all maps {n_eff:.0f} +- "
              f"{n_eff_err:.0f}, on the upper half only {n_tail:.0f}; KS of the maxima against "
              f"F^{n_eff:.0f}: p = {ks.pvalue:.2g}.  Euler-characteristic fit (maxima above TS "
              f"{EC_FIT_FROM:g}, {ec['n_tail']} maps): P(max TS > u) = Psi(sqrt u) + L1 "
              f"e^(-u/2)/(2 pi) + L2 sqrt(u) e^(-u/2)/(2 pi)^(3/2) with L1 = 0 and "
              f"L2 = {ec['L2']:.0f} +- {ec['L2_err']:.0f}")
        print("\n| TS threshold t | maps with max > t (measured, 2-sigma) | F^N_eff (constant "
              f"N_eff = {n_eff:.0f}) | Euler-characteristic fit | N_eff(t) measured "
              "[2-sigma] | L2(t) measured [2-sigma] |")
        print("|---:|---|---:|---:|---|---|")
        above = {}
        for t in (6.0, 9.0, 12.0, 14.0, 16.0, 18.0, 20.0, 25.0):
            k = int(np.count_nonzero(mx > t))
            lo, hi = wilson(k, n)
            above[t] = {"k": k, "n_eff": n_eff_at(k / n, t), "n_eff_lo": n_eff_at(lo, t),
                        "n_eff_hi": n_eff_at(hi, t), "ec": float(ec_sf(t, ec["L1"], ec["L2"])),
                        "l2": l2_at(k / n, t), "l2_lo": l2_at(lo, t), "l2_hi": l2_at(hi, t)}
            ne = (f"{above[t]['n_eff']:.0f} [{above[t]['n_eff_lo']:.0f}, "
                  f"{above[t]['n_eff_hi']:.0f}]" if k else f"< {above[t]['n_eff_hi']:.0f}")
            l2t = (f"{above[t]['l2']:.0f} [{above[t]['l2_lo']:.0f}, {above[t]['l2_hi']:.0f}]"
                   if k else f"< {above[t]['l2_hi']:.0f}")
            print(f"| {t:g} | {fraction(k, n)} | {1 - mix_cdf(t) ** n_eff:.4f} | "
                  f"{above[t]['ec']:.4f} | {ne} | {l2t} |")
        print("\n| false detections per map | TS threshold: empirical quantile [2-sigma] | "
              "Euler-characteristic fit | constant N_eff | sqrt(TS) (EC fit) | "
              "single-position p | trials factor |")
        print("|---|---|---:|---:|---:|---:|---:|")
        thr = {}
        for alpha in (0.01, 0.001):
            q, lo, hi = quantile_interval(mx, 1 - alpha)
            t_const = threshold_for(alpha, n_eff)
            t_ec = ec_threshold(alpha, ec["L1"], ec["L2"])
            t_ec_lo = ec_threshold(alpha, ec["L1"], ec["L2"] - 2 * ec["L2_err"])
            t_ec_hi = ec_threshold(alpha, ec["L1"], ec["L2"] + 2 * ec["L2_err"])
            emp = (f"{q:.1f} [{lo:.1f}, {hi if np.isfinite(hi) else mx.max():.1f}"
                   f"{'' if np.isfinite(hi) else '+'}]" if n * alpha >= 3 else
                   f"not measurable ({n * alpha:.0f} map expected above)")
            p1 = float(mix_sf(t_ec))
            print(f"| {alpha:.1%} | {emp} | {t_ec:.1f} [{t_ec_lo:.1f}, {t_ec_hi:.1f}] | "
                  f"{t_const:.1f} | {np.sqrt(t_ec):.2f} | {p1:.2e} | {alpha / p1:.0f} |")
            thr[alpha] = {"empirical": [q, lo, hi], "ec": [t_ec, t_ec_lo, t_ec_hi],
                          "constant_n_eff": t_const, "single_p": p1, "trials": alpha / p1}
        print("\nother field sizes (square fields, same pixels and instrument; L2 scales with "
              "the area, L1 with the side):\n")
        print("| field | pixels | TS for 1 % / map | TS for 0.1 % / map | trials factor at 0.1 % |")
        print("|---|---:|---:|---:|---:|")
        scaled = []
        for side in (10.0, 20.0, 40.0, 80.0):
            f = side / 20.0
            l1, l2 = ec["L1"] * f, ec["L2"] * f * f
            t1, t01 = ec_threshold(0.01, l1, l2), ec_threshold(0.001, l1, l2)
            print(f"| {side:g} x {side:g} deg | {round(n_pix * f * f)} | {t1:.1f} | {t01:.1f} "
                  f"| {0.001 / mix_sf(t01):.0f} |")
            scaled.append({"side_deg": side, "ts_1pc": t1, "ts_01pc": t01})
        zero_pix = p["n_zero"].sum() / (n * n_pix)
        pix_tail = p["n_above"].sum(axis=0) / (n * n_pix)
        print(f"\nevery pixel of every map (marginal, correlated within a map): P(TS = 0) = "
              f"{zero_pix:.4f} (0.5), " + ", ".join(
                  f"P(TS > {t:g}) = {f:.2e} ({mix_sf(t):.2e})"
                  for t, f in zip(p["thresholds"], pix_tail, strict=True)))
        summary["mapmax"] = {"n": n, "n_pixels": n_pix, "median": t_med, "n_eff": n_eff,
                             "n_eff_err": n_eff_err, "n_eff_tail": n_tail,
                             "ks_p": float(ks.pvalue), "ec": ec, "thresholds": thr,
                             "above": above, "scaled": scaled,
                             "pixel_zero_fraction": float(zero_pix)}
    if "coverage" in res:
        p = res["coverage"]
        snr_a = np.sqrt(p["ts_asimov"])
        n = snr_a.size
        in68, in90 = p["in68"].astype(bool), p["in90"].astype(bool)
        delta = p["ts"] - p["ts_truth"]
        w68, w90 = delta <= chi2.ppf(0.68, 2), delta <= chi2.ppf(0.9, 2)
        f_in = (p["flux"] >= p["flux_lo"]) & (p["flux"] <= p["flux_hi"])
        print(f"\n### 3. Coverage of the localisation regions, {n} injected sources "
              f"(theta {THETA_RANGE[0]:g}-{THETA_RANGE[1]:g} deg, expected SNR "
              f"{snr_a.min():.1f}-{snr_a.max():.1f}; {p['seconds']:.0f} s)\n")
        print("| expected SNR | n | median r90 (deg) | in 68 % region | in 90 % region | "
              "Wilks 68 % (2dlnL < 2.28) | Wilks 90 % (2dlnL < 4.61) | flux in 1-sigma "
              "interval |")
        print("|---|---:|---:|---|---|---|---|---|")
        rows = []
        edges = COVERAGE_BINS
        for lo, hi in [*pairwise(edges), (0.0, np.inf)]:
            sel = (snr_a >= lo) & (snr_a < hi)
            k = int(sel.sum())
            label = bin_label(lo, hi)
            med = float(np.median(p["r90"][sel])) if k else np.nan
            print(f"| {label} | {k} | {med:.3f} | {fraction(in68[sel].sum(), k)} | "
                  f"{fraction(in90[sel].sum(), k)} | {fraction(w68[sel].sum(), k)} | "
                  f"{fraction(w90[sel].sum(), k)} | {fraction(f_in[sel].sum(), k)} |")
            rows.append({"bin": label, "n": k, "in68": int(in68[sel].sum()),
                         "in90": int(in90[sel].sum()), "wilks68": int(w68[sel].sum()),
                         "wilks90": int(w90[sel].sum()), "flux1s": int(f_in[sel].sum()),
                         "median_r90": med})
        ks_w = kstest(delta, chi2(2).cdf)
        print(f"\n2 delta ln L of the true position (TS at the fit - TS at the truth): mean "
              f"{delta.mean():.3f} (chi2_2: 2), KS against chi2_2: D = {ks_w.statistic:.3f}, "
              f"p = {ks_w.pvalue:.2f}; median r68/r90 {np.median(p['r68'] / p['r90']):.3f} "
              f"(Gaussian {np.sqrt(np.log(1 / 0.32) / np.log(10)):.3f}); every region closed: "
              f"{bool(np.all(p['closed'])) if 'closed' in p else 'n/a'}; measured / expected "
              f"TS: median {np.median(p['ts'] / p['ts_asimov']):.3f}")
        far = int(np.count_nonzero(p["peak_sep"] > 1.0))
        neg = int(np.count_nonzero(delta < -0.05))
        print(f"\nfit diagnostics: TS-map peak > 1 deg from the truth in {far} cases; fitted "
              f"position worse than the truth (TS_truth > TS_fit + 0.05) in {neg}; median "
              f"fit {np.median(p['t_fit']):.2f} s, localise {np.median(p['t_localise']):.2f} s; "
              f"points in the 90 % region: median {np.median(p['n90']):.0f}, min "
              f"{p['n90'].min()}")
        s68, s90 = p["sys_in68"].astype(bool), p["sys_in90"].astype(bool)
        w68n, w90n = p["sys_in68_without"].astype(bool), p["sys_in90_without"].astype(bool)
        print(f"\nsystematic term: truth shifted by N(0, {SIGMA_SYS} deg) per axis\n")
        print("| expected SNR | n | in 68 %, systematic=0 | in 90 %, systematic=0 | "
              f"in 68 %, systematic={SIGMA_SYS} | in 90 %, systematic={SIGMA_SYS} |")
        print("|---|---:|---|---|---|---|")
        sys_rows = []
        for lo, hi in [*pairwise(edges), (0.0, np.inf)]:
            sel = (snr_a >= lo) & (snr_a < hi)
            k = int(sel.sum())
            label = bin_label(lo, hi)
            print(f"| {label} | {k} | {fraction(w68n[sel].sum(), k)} | "
                  f"{fraction(w90n[sel].sum(), k)} | {fraction(s68[sel].sum(), k)} | "
                  f"{fraction(s90[sel].sum(), k)} |")
            sys_rows.append({"bin": label, "n": k, "in68_without": int(w68n[sel].sum()),
                             "in90_without": int(w90n[sel].sum()),
                             "in68": int(s68[sel].sum()), "in90": int(s90[sel].sum())})
        law = r90_law(np.sqrt(p["ts"]), p["r90"] / meta["scale_deg"])
        print(f"\n### 6. r90 vs SNR (b/L = {meta['scale_deg']:.3f} deg)\n")
        print(f"RM: r90/(b/L) = {law['A']:.3f} SNR^({law['slope']:.3f} +- "
              f"{law['slope_err']:.3f}) (scatter {law['rms_dex']:.3f} dex); at the BAT slope "
              f"-0.7: {law['A_at_bat_slope']:.3f} SNR^-0.7; Swift-BAT: {law['bat_A']:.3f} "
              f"SNR^-0.7")
        print("\n| SNR | RM r90 / (b/L) (fit) | BAT r90 / scale | RM / BAT | RM r90 (arcmin) |")
        print("|---:|---:|---:|---:|---:|")
        law_rows = []
        for x in (6.0, 10.0, 20.0, 30.0, 50.0):
            rm = law["A"] * x ** law["slope"]
            bat = float(bat_r90_scaled(x))
            print(f"| {x:g} | {rm:.4f} | {bat:.4f} | {rm / bat:.2f} | "
                  f"{rm * meta['scale_deg'] * 60:.1f} |")
            law_rows.append({"snr": x, "rm": rm, "bat": bat})
        if figure is not None:
            make_figure(p, law, meta["scale_deg"], figure)
            print(f"\nfigure: {figure.relative_to(ROOT)}")
        summary["coverage"] = {"n": n, "rows": rows, "sys_rows": sys_rows,
                               "wilks_mean": float(delta.mean()), "wilks_ks_p": float(ks_w.pvalue),
                               "peak_far": far, "fit_worse_than_truth": neg,
                               "median_t_fit": float(np.median(p["t_fit"])),
                               "median_t_localise": float(np.median(p["t_localise"]))}
        summary["r90"] = {**law, "rows": law_rows}
    if "ul" in res:
        p = res["ul"]
        n = p["ts"].size
        snr_a = np.sqrt(p["ts_asimov"])
        cov = p["ul"] >= p["flux"]
        zero = p["flux"] <= 0
        ok = np.isfinite(p["ul_fit"])
        dul = float(np.max(np.abs(p["ul_fit"][ok] / p["ul"][:ok.sum()] - 1))) \
            if ok.any() else np.nan
        print(f"\n### 4. Upper limits ({UL_CONFIDENCE:.0%}) at the true position, {n} "
              f"faint sources ({p['seconds']:.0f} s)\n")
        print("| true flux (expected SNR) | n | median TS | UL >= true flux |")
        print("|---|---:|---:|---|")
        rows = []
        k = int(zero.sum())
        print(f"| 0 | {k} | {np.median(p['ts'][zero]) if k else np.nan:.2f} | "
              f"{fraction(cov[zero].sum(), k)} |")
        rows.append({"bin": "0", "n": k, "covered": int(cov[zero].sum())})
        for lo, hi in [*pairwise(UL_BINS), (0.0, np.inf)]:
            sel = ~zero & (snr_a > lo) & (snr_a <= hi)
            k = int(sel.sum())
            label = "all > 0" if (lo, hi) == (0.0, np.inf) else f"{lo:g}-{hi:g}"
            print(f"| {label} | {k} | {np.median(p['ts'][sel]) if k else np.nan:.2f} | "
                  f"{fraction(cov[sel].sum(), k)} |")
            rows.append({"bin": label, "n": k, "covered": int(cov[sel].sum())})
        print(f"\nTS < 25 in {np.count_nonzero(p['ts'] < 25)}/{n}; fit() at the same "
              f"position on the first {ok.sum()}: max |UL_fit / UL_scan - 1| = {dul:.1e}")
        summary["ul"] = {"n": n, "rows": rows, "max_rel_ul_fit": dul}
    if "mc" in res:
        p = res["mc"]
        nb = int(p["n_bins"])
        print(f"\n### 5. Monte Carlo events vs Poisson draws of the exact model "
              f"({p['seconds']:.0f} s)\n")
        print(f"Poisson deviance against the exact model's expected counts: ~ {nb} +- "
              f"{np.sqrt(2 * nb):.0f} when the counts are drawn from it.\n")
        print("| source (theta, phi) | expected SNR | events (MC / expected) | source events "
              "(MC / expected) | deviance MC | deviance MC source only | deviance draw | "
              "TS MC / draw | offset/r90 MC / draw | flux MC / draw / true |")
        print("|---|---:|---|---|---:|---:|---:|---|---|---|")
        for i in range(p["theta"].size):
            print(f"| ({p['theta'][i]:g}, {p['phi'][i]:g}) | {np.sqrt(p['ts_asimov'][i]):.1f} "
                  f"| {p['n_events'][i]} / {p['expected_events'][i]:.0f} | "
                  f"{p['source_events'][i]} / {p['expected_source_events'][i]:.0f} | "
                  f"{p['dev_mc'][i]:.0f} | {p['dev_mc_source'][i]:.0f} | {p['dev_sim'][i]:.0f}"
                  f" | {p['mc_ts'][i]:.1f} / {p['sim_ts'][i]:.1f} | "
                  f"{p['mc_fit_sep'][i] / p['mc_r90'][i]:.2f} / "
                  f"{p['sim_fit_sep'][i] / p['sim_r90'][i]:.2f} | "
                  f"{p['mc_flux_fit'][i]:.4f} / {p['sim_flux_fit'][i]:.4f} / "
                  f"{p['flux'][i]:.4f} |")
        if "bright_expected" in p:
            ev = np.concatenate([p["bright_events_0"], p["bright_events_1"]]).astype(float)
            ex = np.concatenate([p["bright_expected"], p["bright_expected"]])
            dev = np.concatenate([p["bright_dev_0"], p["bright_dev_1"]])
            rel = ev.sum() / ex.sum() - 1
            print(f"\nbright source alone (flux {MC_BRIGHT}, {ev.size} runs of "
                  f"~{ex.mean():.2e} photons): MC / exact-model total - 1 = {rel * 1e2:+.3f} +- "
                  f"{1e2 / np.sqrt(ex.sum()):.3f} %; per run (sigma) "
                  + ", ".join(f"{z:+.1f}" for z in (ev - ex) / np.sqrt(ex))
                  + f"; deviances {', '.join(f'{d:.0f}' for d in dev)} ({nb} +- "
                  f"{np.sqrt(2 * nb):.0f})")
        summary["mc"] = {k: np.asarray(v).tolist() for k, v in p.items()}
    return summary


PARTS = {"null": part_null, "mapmax": part_mapmax, "coverage": part_coverage, "ul": part_ul,
         "mc": part_mc}


# ----------------------------------------------------------------------------- main
def save(path: Path, res: dict, meta: dict) -> None:
    flat = {f"{part}/{k}": np.asarray(v) for part, d in res.items() for k, v in d.items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, meta=json.dumps(meta), **flat)
    os.replace(tmp, path)


def load(path: Path) -> tuple[dict, dict]:
    z = np.load(path)
    meta = json.loads(str(z["meta"]))
    res: dict = {}
    for key in z.files:
        if key == "meta":
            continue
        part, k = key.split("/", 1)
        res.setdefault(part, {})[k] = z[key]
    return res, meta


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small smoke run")
    ap.add_argument("--report", action="store_true",
                    help="print the tables and draw the figure from the saved results")
    ap.add_argument("--parts", default=None,
                    help="comma-separated parts to (re)run, keeping the others of the saved "
                         "run (default: all, fresh)")
    args = ap.parse_args()
    tag = "_quick" if args.quick else ""
    npz = RESULTS / f"sources_calibration{tag}.npz"
    figure = RESULTS / "sources_r90_quick.png" if args.quick else FIGURE
    if args.report:
        res, meta = load(npz)
        write_summary(npz, summarise(res, meta, figure))
        return
    counts = ({"null": (200, 10), "mapmax": 30, "coverage": 12, "ul": (60, 5), "mc": 1}
              if args.quick else
              {"null": (5000, 50), "mapmax": 5000, "coverage": 200, "ul": (1000, 30), "mc": 4})
    parts = args.parts.split(",") if args.parts else list(PARTS)
    unknown = set(parts) - set(PARTS)
    if unknown:
        raise SystemExit(f"unknown parts {sorted(unknown)}; choose from {list(PARTS)}")
    t_all = time.perf_counter()
    # --parts: rerun those parts and keep the others of the saved run.
    res, meta = load(npz) if args.parts and npz.exists() else ({}, {})
    s = Setup()
    meta.update({
        "machine": f"{platform.processor() or platform.machine()} "
                   f"({platform.system()} {platform.release()})",
        "cores": os.cpu_count(), "numba": numba.__version__,
        "numba_threads": numba.config.NUMBA_NUM_THREADS, "numpy": np.__version__,
        "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
        "python": sys.version.split()[0], "build_s": s.build_s, "scale_deg": s.scale_deg,
        "quick": args.quick, "seed": SEED, "sigma_sys": SIGMA_SYS,
        "command": "python benchmarks/sources_calibration.py" + (" --quick" * args.quick)})
    meta.setdefault("counts", {}).update({k: counts[k] for k in parts})
    run = {"parts": parts, "started": time.strftime("%Y-%m-%d %H:%M"),
           "load_start": os.getloadavg()[0]}
    meta.setdefault("runs", []).append(run)
    say(f"response built in {s.build_s:.1f} s ({s.response.n_det} det x {s.response.n_time} "
        f"bins x {s.response.n_sky} px); b/L = {s.scale_deg:.3f} deg; load "
        f"{run['load_start']:.2f}")
    for part in parts:
        say(f"part {part} ...")
        res[part] = PARTS[part](s, counts[part])
        run["load_end"] = os.getloadavg()[0]
        run["seconds"] = time.perf_counter() - t_all
        save(npz, res, meta)
    write_summary(npz, summarise(res, meta, figure))
    say(f"\nraw results: {npz.relative_to(ROOT)} (+ .json summary)")


def write_summary(npz: Path, summary: dict) -> None:
    with open(npz.with_suffix(".json"), "w") as fh:
        json.dump(summary, fh, indent=1, default=float)


if __name__ == "__main__":
    main()
