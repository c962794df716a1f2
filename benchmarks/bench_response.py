"""Response benchmarks: per-detector kernels, the 19-detector response, operator products.

Run ``python benchmarks/bench_response.py [--repeat 5]``; prints a markdown table of
medians (and the single-thread figures, ``numba.set_num_threads(1)``).  The plain-numpy
column is a straightforward float64 vectorised implementation of the advanced formula with
G1~, written here, timed in the same run.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numba
import numpy as np

from rotmod import DetectorArray, Instrument
from rotmod.profiles import get_model
from rotmod.profiles.advanced import alpha_factor
from rotmod.profiles.base import project
from rotmod.response import MatrixFreeResponse, TimeBinning, build_response
from rotmod.sky import SkyGrid


def median_time(fn, repeat: int) -> float:
    fn()  # warm-up (numba compile / cache load)
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def _F(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return np.arccos(1 - 2 * x) / np.pi - 2 / np.pi * (1 - 2 * x) * np.sqrt(x - x * x)


def numpy_advanced_approx(inst: Instrument, theta, phi, xi) -> np.ndarray:
    """Plain vectorised float64 numpy version of the advanced formula with G1~ (1 detector)."""
    m = inst.mask
    a, b, c = m.slat_width, m.slat_gap, inst.detectors.diameter
    p = a + b
    g = project(inst, theta, phi)
    tau = g.tau
    e_tau = np.exp(-tau)
    alpha = alpha_factor(tau)
    big_m = int(np.floor((a + m.thickness * np.tan(theta).max() + c + p) / (2 * p)))
    cx, sx = np.cos(xi)[:, None], np.sin(xi)[:, None]
    uc = g.X[0][None, :] * cx - g.Y[0][None, :] * sx
    s = g.Sx[None, :] * cx - g.Sy[None, :] * sx
    sa = np.abs(s)
    ws, wa = sa / c, (a - sa) / c
    w = np.mod(np.abs(uc + 0.5 * s), p)
    total = np.zeros_like(uc)
    for k in range(-big_m, big_m + 1):
        xs = 0.5 * (wa + 1.0) - np.abs(w - (0.5 + k) * p) / c
        f_hi, f_lo = _F(xs + ws), _F(xs - wa - ws)
        g0 = (1 - e_tau) * (f_hi - f_lo)
        g1 = alpha * (f_hi - _F(xs) + _F(xs - wa) - f_lo)
        total += g0 - g1
    return np.clip(1.0 - total, 0.0, 1.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    r = max(5, args.repeat)
    inst1 = Instrument.paper()
    inst19 = Instrument(inst1.mask, DetectorArray.hexagonal(3.8, rings=2))
    grid = SkyGrid.paper()
    theta, phi = grid.directions()
    tb = TimeBinning(560)
    xi = tb.angles()
    nthreads = numba.get_num_threads()

    rows = []
    models = ["standard", "advanced-g0", "advanced-approx", "advanced", "exact-fast", "exact"]
    targets = {"standard": "≤ 10", "advanced-approx": "≤ 30", "exact-fast": "≤ 100",
               "exact": "(accurate path)"}
    for name in models:
        mdl = get_model(name)
        t_all = median_time(lambda mdl=mdl: mdl.profile(inst1, theta, phi, xi,
                                                        dtype=np.float32), r)
        numba.set_num_threads(1)
        t_one = median_time(lambda mdl=mdl: mdl.profile(inst1, theta, phi, xi,
                                                        dtype=np.float32), r)
        numba.set_num_threads(nthreads)
        rows.append((f"{name}, 1 detector", t_all, t_one, targets.get(name, "")))

    t_np = median_time(lambda: numpy_advanced_approx(inst1, theta, phi, xi), r)
    ref = get_model("advanced-approx").profile(inst1, theta, phi, xi)
    np_err = np.abs(numpy_advanced_approx(inst1, theta, phi, xi) - ref).max()
    t_adv = rows[models.index("advanced-approx")][1]
    rows.append(("plain numpy float64 advanced-approx, 1 detector", t_np, t_np, ""))

    exact = get_model("exact").profile(inst1, theta, phi, xi)
    fast = get_model("exact-fast").profile(inst1, theta, phi, xi)
    fast_err = np.abs(fast - exact)

    t19 = median_time(lambda: build_response(inst19, grid, tb, "advanced-approx"), r)
    numba.set_num_threads(1)
    t19_1 = median_time(lambda: build_response(inst19, grid, tb, "advanced-approx"), 3)
    numba.set_num_threads(nthreads)
    rows.append(("build_response 19 det, advanced-approx, float32", t19, t19_1, "≤ 1000"))

    mat = build_response(inst19, grid, tb)
    mf = MatrixFreeResponse(inst19, grid, tb, dtype=np.float32)
    rng = np.random.default_rng(0)
    x, y = rng.random(grid.size), rng.random((19, 560))
    t_mpair = median_time(lambda: (mat.forward(x), mat.adjoint(y)), r)
    t_mfpair = median_time(lambda: (mf.forward(x), mf.adjoint(y)), r)
    t_mffa = median_time(lambda: mf.forward_adjoint(x, y), r)
    rows.append(("materialised forward + adjoint, 19 det", t_mpair, float("nan"), ""))
    rows.append(("matrix-free forward + adjoint, 19 det", t_mfpair, float("nan"), ""))
    rows.append(("matrix-free forward_adjoint (one sweep), 19 det", t_mffa, float("nan"), ""))

    print(f"Machine: {platform.machine()}, {os.cpu_count()} cores (numba threads "
          f"{nthreads}), numpy {np.__version__}, numba {numba.__version__}; "
          f"4900 sky x 560 time bins, median of {r} runs\n")
    print("| case | median (ms) | 1 thread (ms) | target (ms) |")
    print("|---|---:|---:|---:|")
    for name, t, t1, tgt in rows:
        one = "" if np.isnan(t1) else f"{1e3 * t1:.1f}"
        print(f"| {name} | {1e3 * t:.1f} | {one} | {tgt} |")
    print()
    print(f"* advanced-approx vs plain numpy: {t_np / t_adv:.0f}x faster (target ≥ 20x); "
          f"max |numpy - numba| = {np_err:.1e}")
    print(f"* exact-fast vs exact: max error {fast_err.max():.1e}, rms "
          f"{np.sqrt(np.mean(fast_err**2)):.1e}")
    print(f"* matrix-free pair / materialised pair = {t_mfpair / t_mpair:.0f}x; "
          f"/ (build + materialised pair) = {t_mfpair / (t19 + t_mpair):.2f}x; "
          f"one-sweep forward_adjoint / (build + pair) = {t_mffa / (t19 + t_mpair):.2f}x")


if __name__ == "__main__":
    main()
