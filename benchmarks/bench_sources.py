"""TS maps: rotmod's per-pixel Newton scan against the straightforward way, and how it scales.

Run ``python benchmarks/bench_sources.py [--repeat 5] [--naive 24]``; prints a markdown table
whose numbers are recorded in docs/sources.md.

The survey instrument of issue 21 (37 detectors of 5 cm under a 3 cm / 3 cm / 3 cm lead mask
1 m up, 300 keV, exact model, 180 mask-angle bins), one source of TS ~ 150 on a flat
background fitted per detector.  For square fields of 20 x 20 to 80 x 80 pixels of 0.5 deg:

* ours: :func:`rotmod.sources.ts_map` on the materialised response, TS only and with upper
  limits and sensitivity (median of ``--repeat``);
* the straightforward way: one independent maximum-likelihood fit per pixel -- the test
  source's flux and the 37 background levels by ``scipy.optimize.minimize`` (L-BFGS-B with the
  analytic gradient, flux >= 0) on the pixel's materialised column -- timed on ``--naive``
  pixels and scaled by the pixel count (its cost is per pixel), with the largest TS
  difference between the two on those pixels.

The last row extrapolates the scan's measured cost per (pixel x bin) to the wide field of
issue 21 (10^6 pixels, 61 detectors, 2000 bins) -- the columns not counted.
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
from rotmod.response import build_response
from rotmod.sky import SkyGrid
from rotmod.sources import PointSource, SkyModel, SourceFitter, ts_map
from rotmod.sources.tsmap import null_state, scan_test_source


def median_time(fn, repeat: int) -> float:
    fn()  # warm-up (numba cache load)
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def naive_ts(fitter: SourceFitter, column: np.ndarray, null_ll: float, b0: np.ndarray) -> float:
    """TS of one pixel by a general-purpose optimiser: flux and every background level."""
    valid, y = fitter.valid, fitter.y
    c = (fitter.exposure * column)[valid]
    n_det = fitter.data.shape[0]
    det = np.broadcast_to(np.arange(n_det)[:, None], fitter.data.shape)[valid]
    e = fitter.exposure[valid]

    def neg(p):
        mu = p[0] * c + p[1:][det] * e
        g_mu = y / mu - 1.0
        grad = np.concatenate([[c @ g_mu], np.bincount(det, e * g_mu, n_det)])
        const = np.where(y > 0, y * np.log(np.where(y > 0, y, 1.0)) - y, 0.0)
        return -(np.sum(y * np.log(mu) - mu - const)), -grad

    res = minimize(neg, np.concatenate([[1e-6], b0]), jac=True, method="L-BFGS-B",
                   bounds=[(0, None)] + [(1e-9, None)] * n_det,
                   options={"ftol": 1e-14, "gtol": 1e-10, "maxiter": 2000})
    return max(2.0 * (-res.fun - null_ll), 0.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--naive", type=int, default=24, help="pixels fitted the naive way")
    ap.add_argument("--sides", type=int, nargs="+", default=[20, 40, 80])
    args = ap.parse_args()
    inst = Instrument(Mask(3, 3, 3, 100), DetectorArray.hexagonal(5, rings=3),
                      rotation_period=60)
    load0 = os.getloadavg()[0]
    print(f"# TS maps: {platform.processor() or platform.machine()}, "
          f"{numba.get_num_threads()} numba threads, load {load0:.2f} at start\n")
    print("| pixels | bins x detectors | TS only (s) | + UL, sensitivity (s) | naive (s, scaled) "
          "| ratio | max abs TS diff | load |")
    print("|---|---|---|---|---|---|---|---|")
    per_value = []
    rng = np.random.default_rng(5)
    for side in args.sides:
        grid = SkyGrid.square(side * 0.5, 0.5)
        resp = build_response(inst, grid, 180, energy=300, dtype=np.float64)
        truth = SkyModel([PointSource((3.3, 47.0), flux=0.05)], background=np.full(37, 2.0))
        data = truth.simulate(resp, 1000.0, seed=1)
        fitter = SourceFitter(resp, data)
        t_ts = median_time(lambda r=resp, d=data, f=fitter: ts_map(r, d, fitter=f),
                           args.repeat)
        state = null_state(fitter, None)
        t_only = median_time(lambda r=resp, f=fitter, s=state: scan_test_source(
            f, s, f.on_bins(r.matrix), 0.0, 0.0), args.repeat)
        ours = scan_test_source(fitter, state, fitter.on_bins(resp.matrix), 0.0, 0.0)[:, 0]
        null_ll = fitter.maximise(SkyModel())[1].loglike
        pixels = rng.choice(grid.size, size=min(args.naive, grid.size), replace=False)
        pixels[0] = int(np.argmax(ours))
        t0 = time.perf_counter()
        naive = [naive_ts(fitter, resp.matrix[:, :, p], null_ll, state[3]) for p in pixels]
        t_naive = (time.perf_counter() - t0) / len(pixels) * grid.size
        diff = float(np.max(np.abs(np.array(naive) - ours[pixels])))
        values = grid.size * fitter.y.size
        per_value.append(t_only / values)
        print(f"| {grid.size} | {fitter.y.size} | {t_only:.3f} | {t_ts:.3f} | {t_naive:.0f} "
              f"| {t_naive / t_only:.0f}x | {diff:.1e} | {os.getloadavg()[0]:.2f} |",
              flush=True)
    wide = 1e6 * 61 * 2000 * float(np.median(per_value))
    print(f"\nExtrapolated TS-only scan of 10^6 pixels x 61 detectors x 2000 bins: "
          f"{wide:.0f} s on this machine (columns not counted).")


if __name__ == "__main__":
    main()
