"""A TS map of a 10^6-pixel wide field: the score screen + exact pass against the exact map.

Run ``python benchmarks/bench_tsmap_wide.py [--side 1000] [--bins 2000] [--repeat 3]``;
prints markdown tables whose numbers are recorded in docs/sources.md.

The wide field of ``bench_radon.py`` (issue 21's speed goal): 61 detectors of 1 cm under a
1 cm / 1 cm / 1 cm mask 114 cm up, 662 keV, ``side x side`` pixels of 0.1 deg, 2000
mask-angle bins, a Radon response at tolerance 1e-3.  Five point sources of SNR ~10-50 on a
background of ~20 counts per bin and detector, fitted per detector; the null is the
background alone (the first map of a detection).

* ours: :func:`rotmod.sources.ts_map` with ``exact_above=25`` (TS only, and with upper
  limits and sensitivity): the score screen from three adjoint products, then the
  likelihood ratio for the pixels the screen puts near or above 25; against the background
  alone (a detection's first map) and with the brightest source in the model (its second);
* the exact map as before (every pixel's column and Newton solve, the kernel ``ts_map``
  uses without ``exact_above``), timed on ``--sample`` random pixels and scaled to the field;
* the straightforward way: one L-BFGS-B fit per pixel (flux and 61 background levels) on
  its column, timed on ``--naive`` pixels and scaled.

Accuracy, against the exact per-pixel likelihood ratio on the sampled pixels and on the
pixels whose screen TS lies just below the exact pass's cut (all, or ``--near`` at random):
the largest TS that the screen left to itself (it must stay below ``exact_above``), the
screen's TS error there, and the two approximations of the screen measured separately (the
squared table of ``adjoint_squared`` and the background correction pooled over detectors).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numba
import numpy as np
from scipy.optimize import minimize

from rotmod import DetectorArray, Instrument, Mask
from rotmod.binning import TimeBinning
from rotmod.response import RadonResponse, build_response
from rotmod.sky import SkyGrid
from rotmod.sources import PointSource, SkyModel, SourceFitter, ts_map
from rotmod.sources.tsmap import null_state, scan_test_source


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t


def naive_ts(fitter: SourceFitter, column: np.ndarray, null_ll: float, b0: np.ndarray) -> float:
    """TS of one pixel by a general-purpose optimiser: flux and every background level."""
    valid = fitter.valid
    c = (fitter.exposure * column)[valid]
    n_det = fitter.data.shape[0]
    det = np.broadcast_to(np.arange(n_det)[:, None], fitter.data.shape)[valid]
    e = fitter.exposure[valid]
    yv = fitter.data.counts[valid]
    const = np.where(yv > 0, yv * np.log(np.where(yv > 0, yv, 1.0)) - yv, 0.0).sum()

    def neg(p):
        mu = p[0] * c + p[1:][det] * e
        g_mu = yv / mu - 1.0
        grad = np.concatenate([[c @ g_mu], np.bincount(det, e * g_mu, n_det)])
        return -(np.sum(yv * np.log(mu) - mu) - const), -grad

    res = minimize(neg, np.concatenate([[1e-6], b0]), jac=True, method="L-BFGS-B",
                   bounds=[(0, None)] + [(1e-9, None)] * n_det,
                   options={"ftol": 1e-14, "gtol": 1e-10, "maxiter": 2000})
    return max(2.0 * (-res.fun - null_ll), 0.0)


def pooling_table() -> None:
    """The screen's pooled background correction against the per-detector one, by distance
    from the axis, for three arrays (materialised exact responses, 40 x 40 pixels, 180
    bins, a flat background): the ratio of the screen's TS to the profiled score's."""
    cases = [("7 x 5 cm, 3/3/3 cm mask at 100 cm", Mask(3, 3, 3, 100), 5.0, 1, 1.0),
             ("37 x 5 cm, same mask", Mask(3, 3, 3, 100), 5.0, 3, 1.0),
             ("61 x 1 cm, 1/1/1 cm mask at 114 cm (the wide field)", Mask(1, 1, 1, 114), 1.0,
              4, 0.5)]
    bands = [(0, 2), (2, 5), (5, 10), (10, 20)]
    print("| array | " + " | ".join(f"theta {a}-{b} deg" for a, b in bands) + " |")
    print("|---|" + "---|" * len(bands))
    for label, mask, radius, rings, pixel in cases:
        inst = Instrument(mask, DetectorArray.hexagonal(radius, rings=rings))
        resp = build_response(inst, SkyGrid.square(40 * pixel, pixel), 180, energy=300,
                              dtype=np.float64)
        p = resp.matrix
        info1 = (p**2).sum((0, 1))
        x = p.sum(1)
        profiled = info1 - (x**2).sum(0) / p.shape[1]
        pooled = info1 - x.sum(0) ** 2 / (p.shape[1] * p.shape[0])
        ratio = profiled / pooled
        theta = resp.grid.directions()[0].to_value("deg").ravel()
        mins = [ratio[(theta >= a) & (theta < b)].min() for a, b in bands]
        print(f"| {label} | " + " | ".join(f"{m:.3f}" for m in mins) + " |")
    print()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--side", type=int, default=1000)
    ap.add_argument("--bins", type=int, default=2000)
    ap.add_argument("--tolerance", type=float, default=1e-3)
    ap.add_argument("--exact-above", type=float, default=25.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--sample", type=int, default=512, help="pixels computed exactly")
    ap.add_argument("--naive", type=int, default=6, help="pixels fitted the naive way")
    ap.add_argument("--near", type=int, default=3000,
                    help="screened pixels just below the cut checked exactly (at most)")
    ap.add_argument("--skip-pooling", action="store_true")
    ap.add_argument("--skip-limits", action="store_true",
                    help="do not time the map with upper limits and sensitivity")
    args = ap.parse_args()
    tau = args.exact_above
    inst = Instrument(Mask(1.0, 1.0, 1.0, 114.0), DetectorArray.hexagonal(1.0, rings=4))
    grid = SkyGrid((args.side, args.side), 0.1)
    print(f"# Wide-field TS map: {platform.processor() or platform.machine()}, "
          f"{numba.get_num_threads()} numba threads, load {os.getloadavg()[0]:.2f} at start\n")
    if not args.skip_pooling:
        pooling_table()
    resp, t_setup = timed(lambda: RadonResponse(inst, grid, TimeBinning(args.bins), 662.0,
                                                tolerance=args.tolerance))
    rng = np.random.default_rng(21)
    theta = np.degrees(np.arccos(rng.uniform(np.cos(np.radians(35.0)), 1.0, 5)))
    phi = rng.uniform(0.0, 360.0, 5)
    fluxes = [2.5, 1.2, 0.8, 0.5, 0.45]
    truth = SkyModel([PointSource((float(t), float(p)), flux=f)
                      for t, p, f in zip(theta, phi, fluxes, strict=True)],
                     background=np.full(resp.n_det, 20.0))
    data = truth.simulate(resp, 1.0, seed=7)
    fitter = SourceFitter(resp, data)
    state = null_state(fitter, None)

    # Ours: screen + exact pass, against the background alone (a detection's first map)
    # and with the brightest source in the model (its second).  A screen alone first loads
    # numba's cache.
    ts_map(resp, data, fitter=fitter, limits=False, exact_above=1e12)
    runs = [timed(lambda: ts_map(resp, data, fitter=fitter, limits=False, exact_above=tau))
            for _ in range(args.repeat)]
    tm = runs[-1][0]
    t_ts = float(np.median([t for _, t in runs]))
    t_lim = float("nan") if args.skip_limits else timed(
        lambda: ts_map(resp, data, fitter=fitter, exact_above=tau))[1]
    second = SkyModel(truth.sources[:1])
    tm2, t_second = timed(lambda: ts_map(resp, data, second, fitter=fitter, limits=False,
                                         exact_above=tau))
    n_exact = int(tm.exact.sum())
    t_adj = timed(lambda: resp.adjoint(np.ones((resp.n_det, resp.n_time))))[1]

    # The exact map as before, per pixel, on a sample (+ the peak), scaled.
    ts_flat = tm.ts.ravel()
    sample = rng.choice(grid.size, args.sample, replace=False)
    sample[0] = int(np.nanargmax(ts_flat))
    cols = resp.columns(sample)  # warm
    (cols, t_cols) = timed(lambda: resp.columns(sample))
    on_bins = fitter.on_bins(cols)
    exact_s, t_scan = timed(lambda: scan_test_source(fitter, state, on_bins, 0.0, 0.0))
    per_pixel = (t_cols + t_scan) / sample.size
    t_exact_map = per_pixel * grid.size

    # The straightforward way, on a few pixels, scaled.
    null_ll = fitter.maximise(SkyModel())[1].loglike
    t0 = time.perf_counter()
    naive = [naive_ts(fitter, cols[:, :, k].astype(float), null_ll, state[3])
             for k in range(args.naive)]
    t_naive = (time.perf_counter() - t0) / args.naive * grid.size
    naive_diff = float(np.max(np.abs(np.array(naive) - exact_s[: args.naive, 0])))

    # Accuracy: the screen's pixels against their exact TS (sample, and every pixel just
    # below the exact pass's cut, where a miss would show).
    screened = ~tm.exact.ravel()
    on_sample = screened[sample]
    d_sample = np.abs(ts_flat[sample] - exact_s[:, 0])[on_sample]
    near = np.flatnonzero(screened & (ts_flat >= 0.75 * tm.screen_cut))
    if near.size > args.near:
        near = np.sort(rng.choice(near, args.near, replace=False))
    near_exact = np.concatenate([
        scan_test_source(fitter, state, fitter.on_bins(resp.columns(near[k:k + 256])),
                         0.0, 0.0)[:, 0] for k in range(0, near.size, 256)]) \
        if near.size else np.zeros(0)
    d_near = np.abs(ts_flat[near] - near_exact)

    # The screen's two approximations on the sample: the squared table, and the pooled
    # background correction (per-detector sums from the columns).
    mu = fitter.expected(fitter.maximise(SkyModel())[0])
    inv = 1.0 / mu
    ex = fitter.exposure
    c64 = cols.astype(np.float64)
    i1_cols = np.einsum("dtn,dt->n", c64**2, ex * ex * inv)
    i1_full = resp.adjoint_squared(ex * ex * inv)[sample]
    xd = np.einsum("dtn,dt->dn", c64, ex * ex * inv)  # flat template: tb = exposure
    hd = np.sum(ex * ex * inv, axis=1)
    info_exact = i1_cols - np.sum(xd**2 / hd[:, None], axis=0)
    info_pooled = i1_cols - xd.sum(0) ** 2 / hd.sum()
    ratio = info_exact / info_pooled  # the screen's TS / the profiled score's TS
    rel_sq = np.abs(i1_full / i1_cols - 1.0)
    load = os.getloadavg()[0]

    print(f"| wide field | value |\n|---|---|\n"
          f"| pixels x detectors x bins | {grid.size} x {resp.n_det} x {resp.n_time} |\n"
          f"| Radon setup (tolerance {args.tolerance:g}) | {t_setup:.1f} s |\n"
          f"| one adjoint product | {t_adj:.1f} s |\n"
          f"| **TS map against the background, screened (TS only), median of "
          f"{args.repeat}** | **{t_ts:.1f} s** |\n"
          f"| its pixels computed exactly (screen TS >= {tm.screen_cut:.1f}) | {n_exact} "
          f"({n_exact / grid.size:.2%}) |\n"
          f"| the same with upper limits and sensitivity | {t_lim:.1f} s |\n"
          f"| **TS map with the brightest source modelled (TS only)** | **{t_second:.1f} s** "
          f"|\n| its pixels computed exactly | {int(tm2.exact.sum())} |\n"
          f"| exact map as before (column + Newton per pixel, scaled from {sample.size}) | "
          f"{t_exact_map:.0f} s ({per_pixel * 1e3:.2f} ms/pixel) |\n"
          f"| one L-BFGS-B fit per pixel (scaled from {args.naive}) | {t_naive:.0f} s |\n"
          f"| ratio: exact map / screened | {t_exact_map / t_ts:.0f}x |\n"
          f"| ratio: naive / screened | {t_naive / t_ts:.0f}x |\n"
          f"| naive vs exact TS (max abs diff) | {naive_diff:.1e} |\n"
          f"| load at end | {load:.2f} |\n")
    print(f"| accuracy of the screened pixels | value |\n|---|---|\n"
          f"| sample: screened pixels / exact TS max | {on_sample.sum()} / "
          f"{exact_s[on_sample, 0].max():.2f} |\n"
          f"| sample: max abs TS error of the screen | {d_sample.max():.3f} |\n"
          f"| pixels with screen TS in [{0.75 * tm.screen_cut:.1f}, "
          f"{tm.screen_cut:.1f}) checked (at most {args.near}, at random) | {near.size} |\n"
          f"| their exact TS: max (must be < {tau:g}) | "
          f"{near_exact.max() if near.size else float('nan'):.2f} |\n"
          f"| their max abs TS error | {d_near.max() if near.size else float('nan'):.3f} |\n"
          f"| squared table vs squared columns, rel. error max / median | "
          f"{rel_sq.max():.1e} / {np.median(rel_sq):.1e} |\n"
          f"| pooled background correction: screen TS / profiled score TS, min / median | "
          f"{ratio.min():.3f} / {np.median(ratio):.4f} |\n"
          f"| peak TS of the map | {np.nanmax(ts_flat):.0f} |\n")


if __name__ == "__main__":
    main()
