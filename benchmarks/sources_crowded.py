"""Crowded field: the iterative detection of rotmod.sources on a field of many sources.

Run ``python benchmarks/sources_crowded.py [--seeds 0 1 2 3 4] [--densities 90 30 12]
[--quick]``; the results go to ``docs/sources_crowded.md`` (the tables printed here, the
figure written to ``docs/figures/sources_crowded.png``, the raw numbers to
``benchmarks/results/sources_crowded.json``).

Set-up (issue 21): the survey instrument (37 x 5 cm detectors under 3/3/3 cm lead slats 1 m
up, 60 s rotation, 300 keV, exact model), 180 bins of 1000 s, a 30 x 30 deg field in 0.5 deg
pixels, background 2 counts/s per detector (each detector's level drawn within +-10 %,
fitted).  Each realisation places ``n`` sources (``--densities``) uniformly in solid angle
at ``theta < 13 deg``, with a power-law logN-logS in significance, ``N(> S) ~ S^-slope`` for
``S`` in ``[snr_min, snr_max]`` (default slope 1.2 on [1.5, 80]).  At n = 90 a field has
1-4 sources at SNR 30-80, 20-34 at SNR 3-10 and 63-75 below SNR 5 (seeds 0-4; the issue's field);
n = 30 and 12 are the same law with fewer sources, to show where confusion sets in.
A source's true SNR is its Asimov significance alone in the field: the flux whose noiseless
data (background + that source) give TS = SNR^2 to a source at its position against the
background refitted (the sensitivity reading of rotmod's TS kernel, with the TS set per
source).  The counts are exact-model Poisson draws (``SkyModel.simulate``: an injection).

Measured per realisation:

* ``detect(response, data, threshold=25)`` -- the full loop (TS maps, peaks, position fits,
  final refit, localisation), timed;
* matching: true sources in order of decreasing SNR each claim the nearest unclaimed
  catalogue source within ``max(2 R90, one pixel)`` of it (R90: the catalogue source's
  90 % region radius, ``Region.radius(0.9)``).  Completeness and flux bias
  ``(fitted - true) / true`` per true-SNR bin; a catalogue source with no true source of SNR
  >= 3 within that radius is a false detection (counted at TS >= 25 and >= 100);
* the confusion baseline: an oracle fit with every true source of SNR > 5 at its true
  position (fixed; fluxes and background fitted, ``fit_with``), then ``ts_map`` of the
  residuals; its local maxima (3 x 3 pixels) more than 0.5 deg from any true source (and,
  like the false detections, from any true source of SNR >= 3) are what confusion alone
  leaves -- the floor against which the false detections are read;
* speed (on the first realisation): the first TS map as ``detect`` computes it (TS, flux,
  upper limit, sensitivity per pixel; and the TS-only pass) against the straightforward way,
  one independent ``scipy.optimize.minimize`` (L-BFGS-B, analytic gradient) of the Poisson
  likelihood over the test flux and the 37 background levels per pixel with the
  materialised response column, timed on a uniform random subset of pixels and scaled by
  the pixel count (its TS is checked against the map's there and on the brightest pixels);
* the field's number of independent beams (column correlations, sidelobes included), the
  ghosts of the first map (its peaks far from every true source of SNR >= 3) and the
  likelihood of the catalogue against the oracle's and the truth's.

``--threads tuned`` (default) re-executes the script with single-threaded OpenBLAS and
passive OpenMP waiting (see docs/sources_crowded.md); ``--report JSON`` reprints the tables
of a saved run.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import sys
import time
from pathlib import Path

import numba
import numpy as np
from scipy.ndimage import maximum_filter
from scipy.optimize import minimize

from rotmod import DetectorArray, Instrument, Mask
from rotmod.conventions import source_direction
from rotmod.reconstruction.data import PoissonData
from rotmod.response import build_response
from rotmod.response.columns import columns_at
from rotmod.sky import SkyGrid
from rotmod.sources import PointSource, SkyModel, SourceFitter, detect, ts_map
from rotmod.sources.detection import confusion_noise
from rotmod.sources.fitting import fit_with, geometric_scale
from rotmod.sources.tsmap import null_state, scan_test_source

# The module (the package binds the name ``detect`` to the function).
detect_module = importlib.import_module("rotmod.sources.detection")
# ``--threads tuned`` (see docs/sources_crowded.md): on a shared 2-core machine, OpenBLAS's
# threads and OpenMP's spin-waiting barriers turn the fits' many small products and kernels
# into scheduler waits.  Set in the environment before numpy and numba start (the script
# re-executes itself with them).
TUNED_THREADS = {"OPENBLAS_NUM_THREADS": "1", "OMP_WAIT_POLICY": "PASSIVE"}
ROOT = Path(__file__).resolve().parent.parent
EXPOSURE = 1000.0  # s per bin
BACKGROUND = 2.0  # counts/s per detector
SNR_BINS = [(3, 5), (5, 7), (7, 10), (10, 20), (20, 80)]


def log(msg: str) -> None:
    print(msg, flush=True)


def survey_instrument() -> Instrument:
    return Instrument(Mask(3, 3, 3, 100), DetectorArray.hexagonal(5, rings=3),
                      rotation_period=60)


def angles_deg(grid: SkyGrid) -> tuple[np.ndarray, np.ndarray]:
    th, ph = grid.directions()
    return np.degrees(th.value), np.degrees(ph.value)


def unit_vectors(theta_deg: np.ndarray, phi_deg: np.ndarray) -> np.ndarray:
    return source_direction(np.radians(theta_deg), np.radians(phi_deg))


def separation_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (deg) between unit vectors ``a (n, 3)`` and ``b (m, 3)``: ``(n, m)``."""
    return np.degrees(np.arccos(np.clip(a @ b.T, -1.0, 1.0)))


# ----------------------------------------------------------------------------- the field
def draw_field(rng: np.random.Generator, n: int, args
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions (theta, phi deg) uniform in solid angle within ``theta_max`` and SNRs from
    the truncated power law ``N(> S) ~ S^-slope`` on ``[snr_min, snr_max]``."""
    cos_min = np.cos(np.radians(args.theta_max))
    theta = np.degrees(np.arccos(rng.uniform(cos_min, 1.0, n)))
    phi = rng.uniform(0.0, 360.0, n)
    a, lo, hi = args.slope, args.snr_min, args.snr_max
    u = rng.uniform(0.0, 1.0, n)
    # Inverse CDF of the truncated Pareto law.
    snr = (lo**-a - u * (lo**-a - hi**-a)) ** (-1.0 / a)
    order = np.argsort(-snr)
    return theta[order], phi[order], snr[order]


def fluxes_for_snr(response, theta: np.ndarray, phi: np.ndarray, snr: np.ndarray,
                   background: np.ndarray) -> np.ndarray:
    """The flux of each source whose Asimov data set alone (background + the source) has
    TS = snr^2 at its position, the background refitted (the kernel's sensitivity)."""
    asimov_null = PoissonData(EXPOSURE * np.repeat(background[:, None], response.n_time, 1),
                              EXPOSURE)
    fitter = SourceFitter(response, asimov_null)
    state = null_state(fitter, SkyModel())
    cols = columns_at(response, (theta, phi))
    out = np.empty(snr.size)
    for k in range(snr.size):
        out[k] = scan_test_source(fitter, state, fitter.on_bins(cols[:, :, k:k + 1]), 2.706,
                                  float(snr[k] ** 2))[0, 4]
    return out


# ----------------------------------------------------------------------------- analysis
def local_maxima(ts: np.ndarray, min_ts: float) -> np.ndarray:
    """Flat indices of the 3 x 3 local maxima of a map with TS >= ``min_ts``."""
    t = np.where(np.isfinite(ts), ts, -np.inf)
    peak = (t == maximum_filter(t, size=3, mode="constant", cval=-np.inf)) & (t >= min_ts)
    return np.flatnonzero(peak)


def match(true_vec: np.ndarray, true_snr: np.ndarray, cat_vec: np.ndarray,
          radius: np.ndarray) -> np.ndarray:
    """Index of the catalogue source each true source claims (-1: none), see module notes."""
    claimed = np.full(len(true_snr), -1)
    if len(cat_vec) == 0:
        return claimed
    sep = separation_deg(true_vec, cat_vec)
    free = np.ones(len(cat_vec), bool)
    for i in np.argsort(-true_snr):
        ok = free & (sep[i] <= radius)
        if ok.any():
            j = int(np.flatnonzero(ok)[np.argmin(sep[i][ok])])
            claimed[i] = j
            free[j] = False
    return claimed


class StepTimes:
    """Time spent in each step of ``detect`` (its TS maps, position fits, final fit,
    localisations): the functions it calls, wrapped while it runs (instrumentation only)."""

    # (``scan_grid``: the TS-only maps of the patched loop, when the module has it.)
    STEPS = tuple((name, owner, attr) for name, owner, attr in (
        ("ts_map", detect_module, "ts_map"), ("scan_grid", detect_module, "scan_grid"),
        ("fit_positions", SourceFitter, "fit_positions"), ("fit_with", detect_module, "fit_with"),
        ("localise", detect_module, "localise")) if hasattr(owner, attr))

    def __init__(self) -> None:
        self.seconds = {name: 0.0 for name, _, _ in self.STEPS}
        self.calls = {name: 0 for name, _, _ in self.STEPS}
        self.t0 = time.perf_counter()
        self._saved: list = []

    def __enter__(self) -> StepTimes:
        for name, owner, attr in self.STEPS:
            fn = getattr(owner, attr)
            self._saved.append((owner, attr, fn))
            setattr(owner, attr, self._wrap(name, fn))
        return self

    def __exit__(self, *exc) -> None:
        for owner, attr, fn in self._saved:
            setattr(owner, attr, fn)

    def _wrap(self, name, fn):
        def timed(*a, **k):
            t = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                dt = time.perf_counter() - t
                self.seconds[name] += dt
                self.calls[name] += 1
                if name in ("ts_map", "scan_grid"):
                    log(f"    TS map {self.calls[name]:3d} ({dt:.1f} s) done at "
                        f"{time.perf_counter() - self.t0:6.1f} s")
        return timed


def independent_beams(response, theta_max: float, n_probe: int = 300) -> dict:
    """How many independent beams the field holds: ``N_pix / mean_i sum_j r_ij^2`` over the
    pixels within ``theta_max``, ``r_ij`` the correlation of the columns of pixels ``i`` and
    ``j`` once each detector's mean is removed (the background levels absorb it) -- the
    beam solid angle ``int B^2`` of radio confusion, sidelobes included.  Also the median
    over pixels of the largest ``|r|`` more than 1 deg away (the highest sidelobe)."""
    th, ph = angles_deg(response.grid)
    field = np.flatnonzero(th < theta_max)
    x = response.block(n=(0, response.n_sky))[:, :, field]
    x = (x - x.mean(axis=1, keepdims=True)).reshape(-1, field.size)
    x /= np.linalg.norm(x, axis=0)
    probe = np.random.default_rng(7).choice(field.size, min(n_probe, field.size),
                                            replace=False)
    r = x[:, probe].T @ x
    vec = unit_vectors(th[field], ph[field])
    far = separation_deg(vec[probe], vec) > 1.0
    side = np.where(far, np.abs(r), 0.0).max(axis=1)
    core = (~far).sum(axis=1)
    return {"pixels": int(field.size), "beam_pixels": float(np.mean((r**2).sum(axis=1))),
            "beams": float(field.size / np.mean((r**2).sum(axis=1))),
            "beam_pixels_core": float(np.mean(np.where(far, 0.0, r**2).sum(axis=1))),
            "core_pixels": float(np.mean(core)),
            "max_sidelobe_r": float(np.median(side))}


def run_seed(seed: int, n_sources: int, response, args) -> dict:
    field_ss, noise_ss = np.random.SeedSequence([seed, n_sources]).spawn(2)
    rng = np.random.default_rng(field_ss)
    theta, phi, snr = draw_field(rng, n_sources, args)
    background = BACKGROUND * rng.uniform(0.9, 1.1, response.n_det)
    flux = fluxes_for_snr(response, theta, phi, snr, background)
    truth = SkyModel([PointSource((t, p), flux=f, name=f"T{k}")
                      for k, (t, p, f) in enumerate(zip(theta, phi, flux, strict=True))],
                     background=background)
    data = truth.simulate(response, EXPOSURE, seed=np.random.default_rng(noise_ss))
    log(f"{n_sources} sources, seed {seed}: SNR {snr.min():.2f}-{snr.max():.1f}, "
        f"{np.sum(snr >= 3)} above 3, {np.sum(snr >= 7)} above 7; detecting ... "
        f"(load {os.getloadavg()[0]:.2f})")
    with StepTimes() as steps:
        t0 = time.perf_counter()
        det = detect(response, data, threshold=args.threshold)
        t_detect = time.perf_counter() - t0
    res = det.result
    cat = det.sources
    cat_pos = np.array([s.position for s in cat]).reshape(-1, 2)
    cat_vec = unit_vectors(cat_pos[:, 0], cat_pos[:, 1])
    r90 = np.array([r.radius(0.9) if r is not None else np.nan for r in det.regions])
    radius = np.maximum(2.0 * r90, response.grid.pixel_size)
    true_vec = unit_vectors(theta, phi)
    claimed = match(true_vec, snr, cat_vec, radius)
    # False: no true source of SNR >= 3 within the catalogue source's radius.
    sep_ct = separation_deg(cat_vec, true_vec)  # (n_cat, n_true)
    near_real = (sep_ct <= radius[:, None]) & (snr[None, :] >= args.false_snr)
    near_any = sep_ct <= radius[:, None]
    false = ~near_real.any(axis=1)
    sep_cc = separation_deg(cat_vec, cat_vec) + 1e3 * np.eye(len(cat))
    log(f"  detect: {len(cat)} sources in {t_detect:.1f} s ({len(det.history)} peaks tried); "
        f"{int(false.sum())} false; steps: " + ", ".join(
            f"{k} {steps.calls[k]} x {v:.1f} s" for k, v in steps.seconds.items()))

    # The oracle: every true source of SNR > 5 at its true position, then the residual map.
    t0 = time.perf_counter()
    fitter = SourceFitter(response, data)
    strong = np.flatnonzero(snr > args.oracle_snr)
    oracle = SkyModel([PointSource((theta[i], phi[i]), flux=flux[i]) for i in strong])
    ofit = fit_with(fitter, oracle, errors=False)
    # Each oracle source's TS in the joint fit (the others refitted without it): what a
    # source of known position can claim in this field.
    oracle_ts = np.array([fitter.source_ts(ofit.model, k, ofit.loglike)
                          for k in range(len(strong))])
    omap = ts_map(response, data, ofit.model, fitter=fitter)
    t_oracle = time.perf_counter() - t0
    ll_null = fitter.maximise(SkyModel())[1].loglike
    ll = {"detect": float(res.loglike - ll_null), "oracle": float(ofit.loglike - ll_null),
          "truth": float(fitter.loglike(truth) - ll_null)}
    pix_th, pix_ph = angles_deg(response.grid)
    pix_vec = unit_vectors(pix_th, pix_ph)

    def peaks(tsmap) -> dict:
        idx = local_maxima(tsmap.ts, args.threshold)
        if idx.size == 0:
            return {"ts_any": [], "ts_real": []}
        sep = separation_deg(pix_vec[idx], true_vec)
        tsv = tsmap.ts.ravel()[idx]
        far_any = sep.min(axis=1) > args.peak_sep
        far_real = (sep[:, snr >= args.false_snr].min(axis=1) > args.peak_sep)
        return {"ts_any": sorted(tsv[far_any].tolist(), reverse=True),
                "ts_real": sorted(tsv[far_real].tolist(), reverse=True)}

    oracle_peaks = peaks(omap)
    residual_peaks = peaks(det.ts_map)
    first_peaks = peaks(det.first_map)  # ghosts: the unmodelled field's coherent sidelobes
    log(f"  oracle ({strong.size} sources) and its residual map in {t_oracle:.1f} s: "
        f"{len(oracle_peaks['ts_any'])} peaks >= {args.threshold:g} away from true sources; "
        f"ln L - ln L(background): detect {ll['detect']:.1f}, oracle {ll['oracle']:.1f}, "
        f"truth {ll['truth']:.1f}")
    src = []
    for i in range(len(snr)):
        j = int(claimed[i])
        k = np.flatnonzero(strong == i)
        src.append({"theta": float(theta[i]), "phi": float(phi[i]), "snr": float(snr[i]),
                    "flux": float(flux[i]), "cat": j,
                    "fitted_flux": float(cat[j].flux) if j >= 0 else None,
                    "offset": float(sep_ct[j, i]) if j >= 0 else None,
                    "oracle_ts": float(oracle_ts[k[0]]) if k.size else None,
                    "oracle_flux": float(ofit.model.sources[k[0]].flux) if k.size else None})
    catalogue = [{"theta": float(cat_pos[j, 0]), "phi": float(cat_pos[j, 1]),
                  "flux": float(cat[j].flux), "ts": float(res.ts[j]), "r90": float(r90[j]),
                  "ts_conf": float(det.ts_confused[j]),
                  "false": bool(false[j]), "near_any_true": bool(near_any[j].any()),
                  "nearest_true": float(sep_ct[j].min()),
                  "nearest_true_snr": float(snr[np.argmin(sep_ct[j])]),
                  "nearest_real": float(sep_ct[j, snr >= args.false_snr].min()),
                  "nearest_other": float(sep_cc[j].min()) if len(cat) > 1 else None,
                  "claimed": bool(np.any(claimed == j))} for j in range(len(cat))]
    history = [{k: (bool(v) if isinstance(v, bool | np.bool_)
                    else v if isinstance(v, str) else float(v))
                for k, v in h.items()} for h in det.history]
    out = {"seed": seed, "n_sources": n_sources, "t_detect": t_detect, "steps": steps.seconds,
           "calls": steps.calls, "t_oracle": t_oracle, "n_oracle": int(strong.size),
           "loglike": ll, "sources": src, "catalogue": catalogue, "history": history,
           "oracle_peaks": oracle_peaks, "residual_peaks": residual_peaks,
           "first_peaks": first_peaks, "background": background.tolist(),
           "confusion": det.confusion,
           "oracle_confusion": confusion_noise(omap, ofit.model.sources,
                                               np.degrees(2.0 * geometric_scale(response)))}
    if args.figure and seed == args.seeds[0]:
        out["_maps"] = (det.first_map.ts, det.ts_map.ts, omap.ts)
    if args.naive and seed == args.seeds[0] and n_sources == args.densities[0]:
        out["speed"] = speed(response, data, args)
    return out


# ----------------------------------------------------------------------------- speed
def naive_pixel(col: np.ndarray, y: np.ndarray, det: np.ndarray, expo: np.ndarray,
                n_det: int, b0: np.ndarray) -> tuple[float, float]:
    """One pixel the straightforward way: maximise ln L of ``mu = f col + b[det] expo`` over
    ``f >= 0`` and the levels ``b`` with scipy (L-BFGS-B on the exact Poisson likelihood,
    analytic gradient), from the null's levels ``b0``.  Returns (ln L, f)."""
    ysafe = np.where(y > 0, y, 1.0)
    # Parameters scaled to order one: the flux in units of 0.01 (~ the TS-25 flux), the
    # levels in units of the null's.
    scale = np.concatenate([[0.01], b0])

    def negll(q: np.ndarray) -> tuple[float, np.ndarray]:
        p = q * scale
        mu = np.maximum(p[0] * col + p[1:][det] * expo, 1e-300)
        r = y / mu - 1.0
        ll = np.sum(y * np.log(mu / ysafe) + y - mu)
        g = np.concatenate([[col @ r], np.bincount(det, r * expo, n_det)])
        return -ll, -g * scale

    q0 = np.concatenate([[0.0], np.ones(n_det)])
    res = minimize(negll, q0, jac=True, method="L-BFGS-B",
                   bounds=[(0.0, None)] + [(1e-9, None)] * n_det,
                   options={"ftol": 1e-15, "gtol": 1e-9, "maxiter": 1000})
    return -float(res.fun), float(res.x[0] * scale[0])


def speed(response, data, args) -> dict:
    fitter = SourceFitter(response, data)
    t0 = time.perf_counter()
    full = ts_map(response, data, fitter=fitter)
    t_full = time.perf_counter() - t0
    state = null_state(fitter, SkyModel())
    t0 = time.perf_counter()
    ts_only = np.empty(0)
    for n0 in range(0, response.n_sky, 4096):
        n1 = min(n0 + 4096, response.n_sky)
        ts_only = np.concatenate([ts_only, scan_test_source(
            fitter, state, fitter.on_bins(response.block(n=(n0, n1))), 0.0, 0.0)[:, 0]])
    t_ts = time.perf_counter() - t0
    # The naive way: timed on a uniform random subset of the pixels the data see (scaled by
    # the pixel count), its TS checked there and on the brightest pixels (the hard fits).
    rng = np.random.default_rng(12345)
    ok = np.flatnonzero(np.isfinite(full.ts.ravel()))
    pix = rng.choice(ok, min(args.naive_pixels, ok.size), replace=False)
    top = ok[np.argsort(-full.ts.ravel()[ok])[:20]]
    n_det = response.n_det
    y = fitter.y
    det = np.broadcast_to(np.arange(n_det)[:, None], data.shape)[fitter.valid]
    expo = fitter.exposure[fitter.valid]
    # The null (background only) in closed form: each level is its detector's mean rate.
    b0 = np.bincount(det, y, n_det) / np.bincount(det, expo, n_det)
    mu0 = b0[det] * expo
    ll0 = float(np.sum(y * np.log(mu0 / np.where(y > 0, y, 1.0)) + y - mu0))
    cols = response.block(n=(0, response.n_sky))  # the materialised matrix

    def naive(pixels: np.ndarray) -> tuple[np.ndarray, float]:
        out = []
        t0 = time.perf_counter()
        for n in pixels:
            col = (fitter.exposure * cols[:, :, n])[fitter.valid]
            ll, _ = naive_pixel(col, y, det, expo, n_det, b0)
            out.append(max(2.0 * (ll - ll0), 0.0))
        return np.array(out), time.perf_counter() - t0

    naive_ts, t_naive = naive(pix)
    top_ts, t_top = naive(top)
    ours = full.ts.ravel()[pix]
    ours_top = full.ts.ravel()[top]
    t_naive_map = t_naive / pix.size * response.n_sky
    return {"pixels": int(response.n_sky), "bins": int(y.size),
            "t_full": t_full, "t_ts_only": t_ts, "naive_pixels": int(pix.size),
            "t_naive_subset": t_naive, "t_naive_map": t_naive_map,
            "ratio_full": t_naive_map / t_full, "ratio_ts_only": t_naive_map / t_ts,
            "t_naive_top": t_top, "n_top": int(top.size),
            "max_abs_dts": float(max(np.max(np.abs(naive_ts - ours)),
                                     np.max(np.abs(top_ts - ours_top)))),
            "max_naive_minus_ours": float(max(np.max(naive_ts - ours),
                                              np.max(top_ts - ours_top))),
            "max_ts_subset": float(ours_top.max()),
            "ts_only_vs_full": float(np.nanmax(np.abs(ts_only - full.ts.ravel())))}


# ----------------------------------------------------------------------------- report
def summarise(runs: list[dict], args) -> dict:
    """Completeness, flux bias and the oracle's per-source TS per true-SNR bin; false
    detections and the confusion baseline per realisation."""
    def col(key: str, default: float = np.nan) -> np.ndarray:
        return np.array([s[key] if s[key] is not None else default
                         for r in runs for s in r["sources"]], dtype=float)

    snr, true, fitted, offset = col("snr"), col("flux"), col("fitted_flux"), col("offset")
    found = col("cat") >= 0
    oracle_ts = col("oracle_ts")
    rel = (fitted - true) / true
    rows = []
    for lo, hi in [*SNR_BINS, (7, np.inf), (10, np.inf)]:
        sel = (snr >= lo) & (snr < hi)
        hit = sel & found
        ors = sel & np.isfinite(oracle_ts)
        rows.append({"bin": f"{lo}-{hi:g}" if np.isfinite(hi) else f">= {lo}",
                     "n": int(sel.sum()), "found": int(hit.sum()),
                     "completeness": float(hit.sum() / max(sel.sum(), 1)),
                     "bias": float(np.median(rel[hit])) if hit.any() else np.nan,
                     "bias_iqr": (np.percentile(rel[hit], [25, 75]).tolist()
                                  if hit.any() else [np.nan, np.nan]),
                     "offset": float(np.median(offset[hit])) if hit.any() else np.nan,
                     "oracle_n": int(ors.sum()),
                     "oracle_ts25": float(np.mean(oracle_ts[ors] >= args.threshold))
                     if ors.any() else np.nan})
    per_seed = []
    for r in runs:
        cat = r["catalogue"]
        per_seed.append({
            "seed": r["seed"], "n_sources": r["n_sources"], "n_cat": len(cat),
            "n_real3": sum(s["snr"] >= args.false_snr for s in r["sources"]),
            "t_detect": r["t_detect"],
            "n_maps": r["calls"]["ts_map"] + r["calls"].get("scan_grid", 0),
            "t_maps": r["steps"]["ts_map"] + r["steps"].get("scan_grid", 0.0),
            "t_positions": r["steps"]["fit_positions"],
            "t_localise": r["steps"]["localise"], "t_final_fit": r["steps"]["fit_with"],
            "false25": sum(c["false"] and c["ts"] >= 25 for c in cat),
            "false100": sum(c["false"] and c["ts"] >= 100 for c in cat),
            "false_ts": sorted((c["ts"] for c in cat if c["false"]), reverse=True),
            "false_near_faint": sum(c["false"] and c["near_any_true"] for c in cat),
            "unclaimed_real": sum((not c["false"]) and (not c["claimed"]) for c in cat),
            "oracle25": len(r["oracle_peaks"]["ts_any"]),
            "oracle100": sum(t >= 100 for t in r["oracle_peaks"]["ts_any"]),
            "oracle25_real": len(r["oracle_peaks"]["ts_real"]),
            "oracle100_real": sum(t >= 100 for t in r["oracle_peaks"]["ts_real"]),
            "oracle_ts": r["oracle_peaks"]["ts_any"],
            "oracle_ts_real": r["oracle_peaks"]["ts_real"],
            "residual25": len(r["residual_peaks"]["ts_real"]),
            "residual_ts": r["residual_peaks"]["ts_real"],
            "rejected": sum(not h["added"] for h in r["history"] if "added" in h),
            "first_ghosts": r["first_peaks"]["ts_real"],
            "false_sep": [c["nearest_real"] for c in cat if c["false"]],
            "sum_snr2": float(sum(s["snr"] ** 2 for s in r["sources"])),
            "loglike": r["loglike"],
            "confusion": r.get("confusion", np.nan),
            "oracle_confusion": r.get("oracle_confusion", np.nan),
            "false25_conf": sum(c["false"] and c.get("ts_conf", np.nan) >= 25 for c in cat),
            "false100_conf": sum(c["false"] and c.get("ts_conf", np.nan) >= 100 for c in cat),
            "real_below_conf": sum((not c["false"]) and c.get("ts_conf", np.nan) < 25
                                   for c in cat),
        })
    return {"bins": rows, "per_seed": per_seed}


def fmt_ts(values: list[float], n: int = 5) -> str:
    if not values:
        return "-"
    s = ", ".join(f"{v:.0f}" for v in values[:n])
    return s + (", ..." if len(values) > n else "")


def pct(v: float, sign: bool = False) -> str:
    if not np.isfinite(v):
        return "-"
    return f"{100 * v:+.1f} %" if sign else f"{100 * v:.0f} %"


def report(results: dict, args, load: tuple[float, ...],
           load_end: tuple[float, ...] | None = None) -> None:
    load_end = os.getloadavg() if load_end is None else load_end
    log(f"\nmachine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"numba {numba.__version__} ({numba.config.NUMBA_NUM_THREADS} threads), numpy "
        f"{np.__version__}; threads {args.threads}; load average at start {load[0]:.2f}, "
        f"at end {load_end[0]:.2f}")
    b = results["beams"]
    log(f"field (theta < {args.theta_max:g} deg): {b['pixels']} pixels, "
        f"{b['beam_pixels']:.0f} pixels per beam (sum of r^2; core within 1 deg "
        f"{b['beam_pixels_core']:.1f} of {b['core_pixels']:.0f} pixels) -> "
        f"{b['beams']:.0f} independent beams; median highest sidelobe |r| "
        f"{b['max_sidelobe_r']:.2f}")
    for n, block in results["densities"].items():
        summary = block["summary"]
        seeds = [p["seed"] for p in summary["per_seed"]]
        n3 = np.mean([p["n_real3"] for p in summary["per_seed"]])
        log(f"\n### {n} sources per field ({n3:.0f} above SNR {args.false_snr:g}: one per "
            f"{b['beams'] / n3:.1f} beams), seeds {', '.join(map(str, seeds))}")
        log("\n| true SNR | sources | detected | completeness | median (fit - true)/true "
            "| IQR | median offset (deg) | oracle: TS >= 25 in the joint fit |")
        log("|---|---:|---:|---:|---:|---|---:|---:|")
        for r in summary["bins"]:
            iqr = (f"{100 * r['bias_iqr'][0]:+.0f} .. {100 * r['bias_iqr'][1]:+.0f} %"
                   if np.isfinite(r["bias"]) else "-")
            off = f"{r['offset']:.2f}" if np.isfinite(r["offset"]) else "-"
            orc = (f"{pct(r['oracle_ts25'])} of {r['oracle_n']}" if r["oracle_n"] else "-")
            log(f"| {r['bin']} | {r['n']} | {r['found']} | {pct(r['completeness'])} | "
                f"{pct(r['bias'], True)} | {iqr} | {off} | {orc} |")
        fs = np.concatenate([p["false_sep"] for p in summary["per_seed"]])
        if fs.size:
            log(f"\nfalse detections: {fs.size}, distance to the nearest true source of SNR >= "
                f"{args.false_snr:g}: median {np.median(fs):.2f} deg, {np.mean(fs < 1.0):.0%} "
                f"within 1 deg (a source displaced), {np.mean(fs >= 2.0):.0%} beyond 2 deg")
        s2 = np.array([p["sum_snr2"] for p in summary["per_seed"]])
        log(f"confusion: sqrt(sum SNR^2 / beams) = {np.median(np.sqrt(s2 / b['beams'])):.1f} "
            "sigma (median over realisations) before any source is modelled")
        log("\nfirst TS map (background only), highest local maxima more than "
            f"{args.peak_sep:g} deg from every true source of SNR >= {args.false_snr:g} "
            "(ghosts): " + "; ".join(f"seed {p['seed']}: {fmt_ts(p['first_ghosts'], 3)}"
                                     for p in summary["per_seed"]))
        log("\n| seed | catalogue | false TS>=25 | false TS>=100 | false TS | oracle peaks "
            ">=25 (>=100) | oracle peak TS | oracle peaks far from SNR>=3: >=25 (>=100) | "
            "residual peaks >=25 | ln L gain: detect / oracle / truth | detect (s) | TS maps "
            "| positions (s) | final fit (s) | localise (s) |")
        log("|---|---:|---:|---:|---|---:|---|---:|---:|---|---:|---:|---:|---:|---:|")
        for p in summary["per_seed"]:
            ll = p["loglike"]
            log(f"| {p['seed']} | {p['n_cat']} | {p['false25']} | {p['false100']} | "
                f"{fmt_ts(p['false_ts'])} | {p['oracle25']} ({p['oracle100']}) | "
                f"{fmt_ts(p['oracle_ts'])} | {p['oracle25_real']} ({p['oracle100_real']}) | "
                f"{p['residual25']} | {ll['detect']:.0f} / {ll['oracle']:.0f} / "
                f"{ll['truth']:.0f} | {p['t_detect']:.0f} | {p['n_maps']} x, "
                f"{p['t_maps']:.0f} s | {p['t_positions']:.0f} | {p['t_final_fit']:.0f} | "
                f"{p['t_localise']:.0f} |")
        t = np.array([p["t_detect"] for p in summary["per_seed"]])
        log(f"\ndetection loop: median {np.median(t):.0f} s (range {t.min():.0f}-{t.max():.0f} s)")
        log("\n| seed | confusion sigma_c: detect / oracle residual | false TS_CONF >= 25 "
            "(>= 100) | real sources with TS_CONF < 25 |")
        log("|---|---|---:|---:|")
        for p in summary["per_seed"]:
            log(f"| {p['seed']} | {p['confusion']:.2f} / {p['oracle_confusion']:.2f} | "
                f"{p['false25_conf']} ({p['false100_conf']}) | {p['real_below_conf']} |")
    sp = results.get("speed")
    if sp:
        log(f"\n| TS map, {sp['pixels']} px x {sp['bins']} bins | time (s) | naive / this |")
        log("|---|---:|---:|")
        log(f"| ts_map (TS, flux, UL, sensitivity; as detect calls it) | {sp['t_full']:.2f} | "
            f"{sp['ratio_full']:.1f} |")
        log(f"| TS-only pass (scan_test_source, q_ul = q_sens = 0) | {sp['t_ts_only']:.2f} | "
            f"{sp['ratio_ts_only']:.1f} |")
        log(f"| naive: scipy L-BFGS-B per pixel (38 parameters), {sp['naive_pixels']} random "
            f"px timed ({sp['t_naive_subset']:.1f} s), scaled | {sp['t_naive_map']:.0f} | 1 |")
        log(f"\nnaive vs ts_map TS on those pixels and the {sp['n_top']} brightest (naive "
            f"{sp['t_naive_top'] / sp['n_top'] * 1e3:.0f} ms per pixel there): max |dTS| = "
            f"{sp['max_abs_dts']:.2g} (max naive - ours {sp['max_naive_minus_ours']:+.2g}; "
            f"highest TS {sp['max_ts_subset']:.0f})")


def figure(results: dict, response, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [next(r for r in block["runs"] if "_maps" in r)
            for block in results["densities"].values()]
    grid = response.grid
    h = 0.5 * grid.shape[1] * grid.pixel_size
    ext = (grid.center[0] - h, grid.center[0] + h, grid.center[1] - h, grid.center[1] + h)
    fig, axes = plt.subplots(len(rows), 3, figsize=(17, 5.4 * len(rows)),
                             constrained_layout=True, squeeze=False)
    for row, r in zip(axes, rows, strict=True):
        first, resid, oracle = r["_maps"]
        snr = np.array([s["snr"] for s in r["sources"]])
        tx, ty = grid.to_tangent(np.array([s["theta"] for s in r["sources"]]),
                                 np.array([s["phi"] for s in r["sources"]]))
        cat = r["catalogue"]
        cx, cy = grid.to_tangent(np.array([c["theta"] for c in cat]),
                                 np.array([c["phi"] for c in cat]))
        false = np.array([c["false"] for c in cat], bool)
        panels = [(first, f"{r['n_sources']} sources, seed {r['seed']}: first TS map"),
                  (resid, f"residual TS map after detect ({len(cat)} sources)"),
                  (oracle, "oracle residual (true SNR > 5 at true positions)")]
        for ax, (ts, title) in zip(row, panels, strict=True):
            im = ax.imshow(np.sqrt(np.maximum(ts, 0)), origin="lower", extent=ext,
                           cmap="viridis", vmin=0,
                           vmax=np.sqrt(np.nanmax(first)) if ts is first else 10.0)
            fig.colorbar(im, ax=ax, shrink=0.8, label="sqrt(TS)")
            ax.scatter(tx, ty, s=4 + 4 * snr, facecolors="none", edgecolors="w",
                       linewidths=0.8, label="true (area ~ SNR)")
            if ts is not oracle:
                ax.scatter(cx[~false], cy[~false], marker="x", c="r", s=30, linewidths=1.2,
                           label="detected")
                ax.scatter(cx[false], cy[false], marker="x", c="orange", s=60,
                           linewidths=2, label="false")
            ax.set_title(title)
            ax.set_xlabel("x (deg)")
            ax.set_ylabel("y (deg)")
        row[0].legend(loc="lower left", fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    log(f"figure: {path}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--densities", type=int, nargs="+", default=[90, 30, 12],
                    help="sources per field (each a set of realisations)")
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: 1 deg pixels, one seed, 30 sources, 40 naive pixels")
    ap.add_argument("--slope", type=float, default=1.2, help="N(>S) ~ S^-slope")
    ap.add_argument("--snr-min", type=float, default=1.5)
    ap.add_argument("--snr-max", type=float, default=80.0)
    ap.add_argument("--theta-max", type=float, default=13.0)
    ap.add_argument("--fov", type=float, default=30.0)
    ap.add_argument("--pixel", type=float, default=0.5)
    ap.add_argument("--bins", type=int, default=180)
    ap.add_argument("--threshold", type=float, default=25.0)
    ap.add_argument("--false-snr", type=float, default=3.0,
                    help="a catalogue source near a true one of this SNR is not false")
    ap.add_argument("--oracle-snr", type=float, default=5.0)
    ap.add_argument("--peak-sep", type=float, default=0.5, help="deg")
    ap.add_argument("--naive-pixels", type=int, default=300)
    ap.add_argument("--no-naive", dest="naive", action="store_false")
    ap.add_argument("--no-figure", dest="figure", action="store_false")
    ap.add_argument("--threads", choices=["default", "tuned"], default="tuned",
                    help=f"tuned: {TUNED_THREADS} (set before numpy is imported)")
    ap.add_argument("--report", metavar="JSON", default=None,
                    help="print the tables of a saved run (no computation)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/sources_crowded.json"))
    ap.add_argument("--figure-path", default=str(ROOT / "docs/figures/sources_crowded.png"))
    args = ap.parse_args()
    if args.report is not None:
        saved = json.loads(Path(args.report).read_text())
        report(saved, argparse.Namespace(**saved["args"]), tuple(saved["load_start"]),
               tuple(saved["load_end"]))
        return
    if args.threads == "tuned" and any(os.environ.get(k) != v for k, v in TUNED_THREADS.items()):
        os.execve(sys.executable, [sys.executable, *sys.argv], {**os.environ, **TUNED_THREADS})
    if args.quick:
        args.pixel, args.seeds, args.densities, args.naive_pixels = 1.0, args.seeds[:1], [30], 40
        args.out = str(Path(args.out).with_suffix(".quick.json"))
        args.figure_path = str(Path(args.figure_path).with_name("sources_crowded_quick.png"))
    load = os.getloadavg()
    log(f"{' '.join(sys.argv)}; threads {args.threads} "
        f"({', '.join(f'{k}={os.environ.get(k)}' for k in TUNED_THREADS)})\n"
        f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    t0 = time.perf_counter()
    response = build_response(survey_instrument(), SkyGrid.square(args.fov, args.pixel),
                              args.bins, energy=300.0, dtype=np.float64)
    log(f"response {response.n_det} x {response.n_time} x {response.n_sky} (exact, 300 keV) "
        f"built in {time.perf_counter() - t0:.1f} s")
    results: dict = {"beams": independent_beams(response, args.theta_max), "densities": {}}
    for n in args.densities:
        runs = [run_seed(s, n, response, args) for s in args.seeds]
        results["densities"][n] = {"runs": runs, "summary": summarise(runs, args)}
        results["speed"] = results.get("speed") or next(
            (r["speed"] for r in runs if "speed" in r), None)
    report(results, args, load)
    if args.figure:
        figure(results, response, Path(args.figure_path))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    keep = {"beams": results["beams"], "speed": results["speed"],
            "densities": {n: {"summary": b["summary"],
                              "runs": [{k: v for k, v in r.items() if not k.startswith("_")}
                                       for r in b["runs"]]}
                          for n, b in results["densities"].items()}}
    out.write_text(json.dumps({"args": vars(args), "load_start": load,
                               "load_end": os.getloadavg(), **keep}, indent=1, default=float))
    log(f"raw results: {out}")


if __name__ == "__main__":
    main()
