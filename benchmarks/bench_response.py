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

import astropy.units as u
import numba
import numpy as np

from rotmod import DetectorArray, Instrument
from rotmod.materials import PAPER_SIGMA_662
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
    g = project(inst, theta * u.rad, phi * u.rad)
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
    inst1 = Instrument.paper(sigma=PAPER_SIGMA_662)
    # The lab prototype's array: 19 detectors of 3.8 cm under a = b = c = 3.8 cm slats (so
    # that the standard model applies too).
    mask38 = Instrument.paper(a=3.8, sigma=PAPER_SIGMA_662).mask
    inst19 = Instrument(mask38, DetectorArray.hexagonal(3.8, rings=2))
    grid = SkyGrid.paper()
    theta, phi = (v.to_value(u.rad) for v in grid.directions())  # plain rad for numpy
    tb = TimeBinning(560)
    xi = tb.angles()  # plain rad, like theta and phi; the rotmod API gets Quantities
    th_q, ph_q, xi_q = theta * u.rad, phi * u.rad, xi * u.rad
    nthreads = numba.get_num_threads()
    nan = float("nan")

    def both(fn, repeat: int = r) -> tuple[float, float]:
        """Median with numba's default threads and with one thread."""
        t_all = median_time(fn, repeat)
        numba.set_num_threads(1)
        t_one = median_time(fn, repeat)
        numba.set_num_threads(nthreads)
        return t_all, t_one

    rows = []
    models = ["standard", "advanced-g0", "advanced-approx", "advanced", "exact"]
    targets = {"standard": "≤ 10", "advanced-approx": "≤ 30", "exact": "≤ 100"}
    for name in models:
        mdl = get_model(name)
        # profile(): every one of the 560 angles; build_response: the response matrix, which
        # computes 280 bins and repeats them (half-turn symmetry, ResponsePlan.n_distinct).
        prof = both(lambda mdl=mdl: mdl.profile(inst1, th_q, ph_q, xi_q, dtype=np.float32))
        resp = both(lambda mdl=mdl: build_response(inst1, grid, tb, mdl))
        rows.append((f"{name}, 1 detector", *prof, *resp, targets.get(name, "")))

    t_np = median_time(lambda: numpy_advanced_approx(inst1, theta, phi, xi), r)
    ref = get_model("advanced-approx").profile(inst1, th_q, ph_q, xi_q)
    np_err = np.abs(numpy_advanced_approx(inst1, theta, phi, xi) - ref).max()
    t_adv = rows[models.index("advanced-approx")][1]
    rows.append(("plain numpy float64 advanced-approx, 1 detector", t_np, t_np, nan, nan, ""))


    t19 = both(lambda: build_response(inst19, grid, tb, "advanced-approx"), 3)
    rows.append(("build_response 19 det, advanced-approx, float32", nan, nan, *t19, "≤ 1000"))

    rng = np.random.default_rng(0)
    x, y = rng.random(grid.size), rng.random((19, 560))
    pairs = {}
    for name in ("advanced-approx", "standard"):
        mat = build_response(inst19, grid, tb, name)
        mf = MatrixFreeResponse(inst19, grid, tb, name, dtype=np.float32)
        pairs[name] = [
            median_time(lambda mat=mat: (mat.forward(x), mat.adjoint(y)), r),
            median_time(lambda mf=mf: (mf.forward(x), mf.adjoint(y)), r),
            median_time(lambda mf=mf: mf.forward_adjoint(x, y), r),
        ]
        t_m, t_f, t_fa = pairs[name]
        rows.append((f"materialised forward + adjoint, 19 det, {name}", t_m, nan, nan, nan, ""))
        rows.append((f"matrix-free forward + adjoint, 19 det, {name}", t_f, nan, nan, nan,
                     f"≤ {3e3 * t_m:.0f}"))
        rows.append((f"matrix-free forward_adjoint (one sweep), 19 det, {name}", t_fa, nan,
                     nan, nan, ""))

    print(f"Machine: {platform.machine()}, {os.cpu_count()} cores (numba threads "
          f"{nthreads}), numpy {np.__version__}, numba {numba.__version__}; "
          f"4900 sky x 560 time bins, median of {r} runs\n")
    print("| case | profile() (ms) | 1 thread | build_response (ms) | 1 thread | target (ms) |")
    print("|---|---:|---:|---:|---:|---:|")

    def ms(v: float) -> str:
        return "" if np.isnan(v) else f"{1e3 * v:.1f}"

    for name, *times, tgt in rows:
        print(f"| {name} | " + " | ".join(ms(v) for v in times) + f" | {tgt} |")
    print()
    print(f"* advanced-approx profile() vs plain numpy: {t_np / t_adv:.0f}x faster "
          f"(target ≥ 20x); max |numpy - numba| = {np_err:.1e}")
    for name, (t_m, t_f, t_fa) in pairs.items():
        print(f"* {name}: matrix-free pair / materialised pair = {t_f / t_m:.1f}x "
              f"(target ≤ 3x); one-sweep forward_adjoint / materialised pair = "
              f"{t_fa / t_m:.1f}x")


if __name__ == "__main__":
    main()
