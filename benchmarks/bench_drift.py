"""A drifting observation's Radon response: one table and one projection per bin swept
(``RadonDriftResponse``) against one ``RadonResponse`` per attitude interval.

Run ``python benchmarks/bench_drift.py [--repeat 3] [--old-max 100]``; the output is
recorded in ``benchmarks/results/bench_drift.txt`` and ``docs/response.md``.

The lab prototype (19 detectors, a 60 s turn), 662 keV, a 100 x 100 celestial grid of 12'
(a 20 deg field), 560 centre bins, float64, tolerance 1e-4 (the defaults of
``drift_response``).  The gondola drifts 1 deg in RA and 0.5 deg in Dec and turns 40 deg of
roll per 1000 s (an ``AttitudeTable`` sampled every 100 s).  Two series:

* **a fixed flight cut finer**: 1000 s (16.7 turns) in 1, 10, 100, 1000 intervals -- the
  issue's question (the cost per interval of the per-interval sum);
* **10 s steps, a longer flight**: 1, 10, 100, 1000 intervals of 10 s (10 s to 2.8 h) --
  what a balloon's aspect solution gives; the shared operator's cost follows the bins the
  flight sweeps (a splat per (interval, bin) pair), the per-interval sum's the intervals.

Setup = building the operator from the intervals; pair = one forward + one adjoint (medians
of ``--repeat`` after a warm-up).  The per-interval sum is timed up to ``--old-max``
intervals and extrapolated linearly beyond (its cost is one table and one Radon pair per
interval, whatever the interval's length), marked "extrap.".  Accuracy: the products
against the per-interval sum (max |difference| / |x|_1 and / |y|_1), and every value at 16
sampled pixels against the exact model evaluated interval by interval
(``columns_at``, the definition of the drift response).

``--shift`` (run first): the error of treating a small tilt of the pointing as a shift of
the projection along ``w`` (docs/physics.md 2c): pixels in a disc of radius r about the
axis, seen after a tilt by eps (exact: the rotated directions, a projective map of the
tangent plane) and as the tangent-plane shift ``t + b`` (``b`` the image of the axis); max
|ΔP| of the exact model over the 19 detectors and 360 angles.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numba
import numpy as np

from rotmod.io import load_instrument
from rotmod.response import TimeBinning, build_response
from rotmod.response.columns import columns_at
from rotmod.response.drift import drift_response
from rotmod.sky import AttitudeTable, CelestialGrid, DirectionList
from rotmod.testing import dot_test

INST = load_instrument("prototype")
ENERGY = 662.0
BINS = TimeBinning(560)
TOL = 1e-4


def _scenario(duration: float, n: int) -> tuple[CelestialGrid, list]:
    t = np.linspace(0.0, 1e4, 101)  # samples every 100 s of a 2.8 h aspect solution
    table = AttitudeTable(t, 200.0 + 1e-3 * t, -60.0 - 5e-4 * t, np.mod(10.0 + 0.04 * t, 360.0))
    steps = table.intervals(0.0, duration, duration / n)
    mid = table.at(0.5 * duration)
    return CelestialGrid((100, 100), 0.2, mid.ra, mid.dec, mid), steps


def _timed(fn) -> tuple[object, float]:
    t = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t


def _pair_time(op, x, y, repeat: int) -> tuple[float, np.ndarray, np.ndarray]:
    fx, ay = op.forward(x), op.adjoint(y)  # warm-up (numba compile / cache load)
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        op.forward(x)
        op.adjoint(y)
        ts.append(time.perf_counter() - t)
    return float(np.median(ts)), fx, ay


def _row(duration: float, n: int, args, *, accuracy: bool) -> dict:
    grid, steps = _scenario(duration, n)
    rng = np.random.default_rng(0)
    x, y = rng.random(grid.size), rng.random((len(INST.detectors), BINS.n_bins))
    new, t_new = _timed(lambda: drift_response(INST, grid, BINS, steps, energy=ENERGY,
                                               operator="radon", tolerance=TOL))
    p_new, fx, ay = _pair_time(new, x, y, args.repeat)
    row = {"duration": duration, "n": n, "pairs": new.n_pairs, "setup_new": t_new,
           "pair_new": p_new, "table": "x".join(str(v) for v in
                                                 (new.table.shape[0], new._factors.n_w,
                                                  new._factors.n_q))}
    if n <= args.old_max:
        old, t_old = _timed(lambda: drift_response(INST, grid, BINS, steps, energy=ENERGY,
                                                   operator="radon-per-interval",
                                                   tolerance=TOL))
        p_old, fo, ao = _pair_time(old, x, y, max(1, min(args.repeat, 300 // n)))
        row.update(setup_old=t_old, pair_old=p_old, extrap=False,
                   d_fwd=float(np.abs(fx - fo).max() / x.sum()),
                   d_adj=float(np.abs(ay - ao).max() / y.sum()))
        del old
    if accuracy:
        pick = np.random.default_rng(1).choice(grid.size, 16, replace=False)
        exact = columns_at(new, grid.sky_coords()[pick])  # interval by interval, exact model
        unit = np.zeros(grid.size)
        mine = np.empty_like(exact)
        for k, pix in enumerate(pick):
            unit[pix] = 1.0
            mine[:, :, k] = new.forward(unit)
            unit[pix] = 0.0
        row["d_exact"] = float(np.abs(mine - exact).max())
        row["dot"] = dot_test(new, rng=np.random.default_rng(2))
    return row


def _fill_extrapolation(rows: list[dict]) -> None:
    """The per-interval sum beyond ``--old-max``: linear in the intervals from the largest
    measured row (each interval is one table and one Radon pair)."""
    measured = [r for r in rows if "pair_old" in r]
    if not measured:
        return
    ref = max(measured, key=lambda r: r["n"])
    for r in rows:
        if "pair_old" not in r:
            r.update(setup_old=ref["setup_old"] * r["n"] / ref["n"],
                     pair_old=ref["pair_old"] * r["n"] / ref["n"], extrap=True)


def _print(title: str, rows: list[dict]) -> None:
    print(f"\n{title}\n")
    print("| intervals | flight (s) | pairs | setup new (s) | pair new (s) | setup per-interval "
          "(s) | pair per-interval (s) | pair speed-up | max Δ fwd / vs sum | max \\|ΔP\\| vs "
          "exact | dot test |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        ex = " (extrap.)" if r.get("extrap") else ""
        d = (f"{r['d_fwd']:.1e} / {r['d_adj']:.1e}" if "d_fwd" in r else "–")
        print(f"| {r['n']} | {r['duration']:.0f} | {r['pairs']} | {r['setup_new']:.2f} | "
              f"{r['pair_new']:.3f} | {r['setup_old']:.2f}{ex} | {r['pair_old']:.3f}{ex} | "
              f"{r['pair_old'] / r['pair_new']:.1f}× | {d} | "
              f"{r['d_exact']:.1e} | {r['dot']:.1e} |" if "d_exact" in r else
              f"| {r['n']} | {r['duration']:.0f} | {r['pairs']} | {r['setup_new']:.2f} | "
              f"{r['pair_new']:.3f} | {r['setup_old']:.2f}{ex} | {r['pair_old']:.3f}{ex} | "
              f"{r['pair_old'] / r['pair_new']:.1f}× | {d} | – | – |")


def shift_error() -> None:
    """Max |ΔP| of the shift approximation of a tilt, by field radius and tilt."""
    print("\n| field radius | tilt | max \\|t\\|² ε (w warp) | max \\|ΔP\\| shift vs exact |")
    print("|---:|---:|---:|---:|")
    bins = TimeBinning(360)
    for radius in (7.0, 14.0, 25.0):
        rho = np.sqrt(np.linspace(0.0, 1.0, 12)) * np.tan(np.radians(radius))
        ang = np.radians(np.arange(0.0, 360.0, 22.5))
        t = np.stack([np.outer(rho, np.cos(ang)).ravel(), np.outer(rho, np.sin(ang)).ravel()],
                     axis=1)
        u = np.column_stack([t, np.ones(len(t))])
        for tilt_arcmin in (0.5, 2.0, 10.0, 60.0):
            e = np.radians(tilt_arcmin / 60.0)
            rot = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(e), -np.sin(e)],
                            [0.0, np.sin(e), np.cos(e)]])  # a tilt about instrument x
            v = u @ rot.T
            exact = v[:, :2] / v[:, 2:]
            b = rot[:2, 2] / rot[2, 2]  # where the axis goes: the shift
            shifted = t + b
            p = [build_response(INST, DirectionList(np.degrees(np.arctan(np.hypot(*q.T))),
                                                    np.degrees(np.arctan2(q[:, 1], q[:, 0]))),
                                bins, "exact", ENERGY, dtype=np.float64).matrix
                 for q in (exact, shifted)]
            warp = float((np.hypot(*t.T) ** 2).max() * e)
            print(f"| {radius:g}° | {tilt_arcmin:g}′ | {warp:.1e} | "
                  f"{np.abs(p[0] - p[1]).max():.1e} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--old-max", type=int, default=100,
                    help="largest number of intervals the per-interval sum is timed for")
    ap.add_argument("--counts", type=int, nargs="+", default=[1, 10, 100, 1000])
    ap.add_argument("--shift", action="store_true", help="also the shift approximation's error")
    args = ap.parse_args()
    load0 = os.getloadavg()
    print(f"# bench_drift: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
          f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, numba "
          f"{numba.__version__} ({numba.get_num_threads()} threads), numpy {np.__version__}")
    print(f"# prototype (19 det), {ENERGY:g} keV, 100 x 100 x 12' celestial grid, "
          f"{BINS.n_bins} {BINS.mode} bins, float64, tolerance {TOL:g}; "
          f"median of {args.repeat} pairs; load average at start {load0[0]:.2f} "
          f"{load0[1]:.2f} {load0[2]:.2f}")
    if args.shift:
        print("\nThe error of a tilt treated as a shift along w (prototype, exact model)")
        shift_error()
    fixed = [_row(1000.0, n, args, accuracy=True) for n in args.counts]
    _fill_extrapolation(fixed)
    _print("A fixed 1000 s flight (16.7 turns) cut into more intervals", fixed)
    steps = [_row(10.0 * n, n, args, accuracy=False) for n in args.counts]
    _fill_extrapolation(steps)
    _print("10 s steps: the flight grows with the intervals", steps)
    load1 = os.getloadavg()
    print(f"\n# load average at end {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")


if __name__ == "__main__":
    main()
