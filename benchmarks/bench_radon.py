"""The Radon-factorised response: accuracy against the exact model, speed against the others.

Run ``python benchmarks/bench_radon.py [--repeat 9] [--mlem-iter 200] [--skip-wide]``.
Each part runs in its own process (so its peak memory is its own) and prints a markdown
table; the results are recorded in docs/response.md.

* ``accuracy``: every value of the paper-scale response (the lab prototype's 19 detectors,
  ``SkyGrid.paper()`` = 70 x 70 x 12', 560 bins) from ``RadonResponse.materialise()`` against
  ``build_response(..., "exact")``, at 662 and 122 keV and with bin-averaged bins; and the
  same on random geometries (thick masks, wide fields, opaque and thin slats).
* ``paper``: one forward + adjoint pair, Radon vs the materialised matrix (numpy/BLAS) and
  the matrix-free exact model, float32, medians; and what each costs to set up.
* ``wide``: 1000 x 1000 pixels of 6' (a 100 deg field), 61 detectors (hexagonal, 4 rings,
  c = 1 cm), 2000 bins, a = b = h = 1 cm lead at L = 114 cm, 662 keV: setup, one pair, peak
  memory, the ratio to the matrix-free exact product (timed on a slice of its bins in the
  same run and scaled by the bin count: its cost is exactly linear in bins), the accuracy
  on sampled pixels, and an MLEM reconstruction on the operator.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time

import astropy.units as u
import numba
import numpy as np

from rotmod import DetectorArray, Instrument, Mask
from rotmod.io import load_instrument
from rotmod.limits import MemoryBudgetError
from rotmod.response import MatrixFreeResponse, RadonResponse, TimeBinning, build_response
from rotmod.sky import SkyGrid
from rotmod.testing import dot_test


def median_time(fn, repeat: int) -> float:
    fn()  # warm-up (numba compile / cache load)
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t


def peak_gib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # kB -> GiB (Linux)


# ----------------------------------------------------------------------------- parts
def part_accuracy(args) -> dict:
    rows = []
    inst = load_instrument("prototype")
    grid = SkyGrid.paper()
    for energy, tb in ((662.0, TimeBinning(560)), (122.0, TimeBinning(560)),
                       (662.0, TimeBinning(560, "average", 4))):
        radon, t_setup = timed(lambda e=energy, b=tb: RadonResponse(inst, grid, b, e,
                                                                    dtype=np.float64))
        err = np.abs(radon.materialise().matrix
                     - build_response(inst, grid, tb, "exact", energy, dtype=np.float64).matrix)
        rows.append({"case": f"paper grid, prototype, {energy:g} keV, {tb.mode}",
                     "values": int(err.size), "max": float(err.max()),
                     "rms": float(np.sqrt(np.mean(err**2))), "table": list(radon.table.shape),
                     "setup_s": t_setup, "dot": dot_test(radon, rng=np.random.default_rng(7))})
    rng = np.random.default_rng(2026)
    for _ in range(args.random):
        a, b = rng.uniform(0.3, 6.0, 2)
        c, h, big_l = rng.uniform(0.3, 8.0), rng.uniform(0.1, 8.0), rng.uniform(20, 200)
        mu = np.inf if rng.random() < 0.3 else rng.uniform(0.05, 5.0)
        fov = rng.uniform(2.0, 110.0)
        inst_r = Instrument(Mask(a, b, h, big_l, mu=mu),
                            DetectorArray(rng.uniform(-15, 15, (3, 2)), c))
        grid_r = SkyGrid((12, 12), fov / 12, center=tuple(rng.uniform(-10, 10, 2)))
        tb_r = TimeBinning(int(rng.integers(20, 60)) * 2)
        name = (f"random: a {a:.2f} b {b:.2f} c {c:.2f} h {h:.2f} L {big_l:.0f} "
                f"mu {mu:.3g} fov {fov:.0f} deg")
        try:
            radon, t_setup = timed(lambda i=inst_r, g=grid_r, b=tb_r: RadonResponse(
                i, g, b, dtype=np.float64))
        except MemoryBudgetError as exc:
            # The table's size goes as (period / step) (L tan theta_max / step) with the step
            # a fixed fraction of the detector radius: small detectors under wide fields
            # need tables beyond memory.  Recorded, not skipped silently.
            rows.append({"case": name, "refused": str(exc).split(";")[0]})
            continue
        err = np.abs(radon.materialise().matrix
                     - build_response(inst_r, grid_r, tb_r, "exact", dtype=np.float64).matrix)
        rows.append({"case": name,
                     "values": int(err.size), "max": float(err.max()),
                     "rms": float(np.sqrt(np.mean(err**2))), "table": list(radon.table.shape),
                     "setup_s": t_setup, "dot": dot_test(radon, rng=rng)})
    return {"rows": rows}


def part_paper(args) -> dict:
    inst = load_instrument("prototype")
    grid = SkyGrid.paper()
    tb = TimeBinning(560)
    rng = np.random.default_rng(0)
    x = rng.random(grid.size).astype(np.float32)
    y = rng.random((len(inst.detectors), tb.n_bins)).astype(np.float32)
    radon, t_radon = timed(lambda: RadonResponse(inst, grid, tb, 662.0))
    mat, t_build = timed(lambda: build_response(inst, grid, tb, "exact", 662.0))
    free = MatrixFreeResponse(inst, grid, tb, "exact", 662.0, dtype=np.float32)
    r = args.repeat
    return {
        "setup": {"radon": t_radon, "build_response": t_build},
        "pair": {
            "materialised (BLAS)": median_time(lambda: (mat.forward(x), mat.adjoint(y)), r),
            "radon": median_time(lambda: (radon.forward(x), radon.adjoint(y)), r),
            "matrix-free exact": median_time(lambda: free.forward_adjoint(x, y), 3),
        },
        "radon_forward": median_time(lambda: radon.forward(x), r),
        "radon_adjoint": median_time(lambda: radon.adjoint(y), r),
        "matrix_mb": mat.matrix.nbytes / 2**20,
        "table_mb": radon.table.nbytes / 2**20,
        "peak_gib": peak_gib(),
    }


def wide_instrument() -> Instrument:
    # c = 1 cm detectors under a = b = 1 cm slats (the paper's a = b = c), pitch 1.05 c.
    return Instrument(Mask(1.0, 1.0, 1.0, 114.0), DetectorArray.hexagonal(1.0, rings=4))


def part_wide(args) -> dict:
    inst = wide_instrument()
    grid = SkyGrid((1000, 1000), 0.1)
    tb = TimeBinning(2000)
    energy = 662.0
    out: dict = {"tolerance": args.wide_tolerance}
    radon, out["setup_s"] = timed(lambda: RadonResponse(inst, grid, tb, energy,
                                                        tolerance=args.wide_tolerance))
    out["table"] = list(radon.table.shape)
    out["n_q"] = radon._factors.n_q
    out["gemm"] = radon._factors.gemm
    rng = np.random.default_rng(1)
    x = rng.random(grid.size).astype(np.float32)
    y = rng.random((radon.n_det, radon.n_time)).astype(np.float32)
    _, out["forward_s"] = timed(lambda: radon.forward(x))
    _, out["adjoint_s"] = timed(lambda: radon.adjoint(y))
    out["pair_s"] = out["forward_s"] + out["adjoint_s"]
    out["peak_gib_radon"] = peak_gib()
    # Accuracy on sampled pixels against the exact model (the same bins and detectors).
    pix = rng.choice(grid.size, 40, replace=False)
    from rotmod.profiles import get_model

    theta, phi = grid.directions()
    exact = get_model("exact").profile(inst, theta[pix], phi[pix], tb.angles() * u.rad,
                                       energy=energy, dtype=np.float64)
    out["sampled_values"] = int(exact.size)
    out["sampled_max_dP"] = float(np.abs(radon.columns(pix) - exact).max())
    # Today's matrix-free exact product, timed on a slice of its (half-turn distinct) bins.
    free = MatrixFreeResponse(inst, grid, tb, "exact", energy, dtype=np.float32)
    n_slice = 2
    _, t_slice = timed(lambda: free.plan.block(t=(0, n_slice)))
    out["dense_product_s_est"] = t_slice * free.n_distinct / n_slice
    out["ratio"] = out["dense_product_s_est"] / (0.5 * out["pair_s"])
    if args.mlem_iter:
        from rotmod.reconstruction import StoppingRule, reconstruct

        truth = np.zeros(grid.shape)
        for iy, ix, flux in ((500, 500, 40.0), (520, 470, 25.0), (200, 800, 30.0),
                             (850, 150, 20.0)):
            truth[iy, ix] = flux
        expo = 200.0
        counts = rng.poisson(expo * (radon.forward(truth.ravel()).astype(np.float64) + 2.0))
        rule = StoppingRule(max_iter=args.mlem_iter, chi2_dof=None, rel_tol=None)
        res, out["mlem_s"] = timed(lambda: reconstruct(radon, counts, "mlem", exposure=expo,
                                                       background=2.0, stopping=rule))
        img = res.image
        # Where the image peaks within 15 pixels of each source (the pair is 36 px apart).
        peaks = []
        for iy, ix in ((500, 500), (520, 470), (200, 800), (850, 150)):
            win = img[iy - 15:iy + 16, ix - 15:ix + 16]
            dy, dx = np.unravel_index(int(np.argmax(win)), win.shape)
            peaks.append([int(dy) - 15, int(dx) - 15])
        out["mlem_iter"] = res.n_iter
        out["mlem_peak_offsets_px"] = peaks
    out["peak_gib"] = peak_gib()
    return out


PARTS = {"accuracy": part_accuracy, "paper": part_paper, "wide": part_wide}


def run_part(name: str, args) -> dict:
    cmd = [sys.executable, __file__, "--part", name, "--repeat", str(args.repeat),
           "--mlem-iter", str(args.mlem_iter), "--random", str(args.random),
           "--wide-tolerance", str(args.wide_tolerance)]
    done = subprocess.run(cmd, check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def report(results: dict) -> None:
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"numba {numba.__version__} ({numba.config.NUMBA_NUM_THREADS} threads), numpy "
          f"{np.__version__}; load average {os.getloadavg()[0]:.2f}")
    if "accuracy" in results:
        print("\n| response (tolerance 1e-4) | values compared | max abs(dP) | rms | "
              "table (J x K R) | dot test (rel.) | setup (s) |")
        print("|---|---:|---:|---:|---|---:|---:|")
        for r in results["accuracy"]["rows"]:
            if "refused" in r:
                print(f"| {r['case']} | refused: {r['refused']} | | | | | |")
                continue
            print(f"| {r['case']} | {r['values']:,} | {r['max']:.2e} | {r['rms']:.1e} | "
                  f"{r['table'][0]} x {r['table'][1]} | {r['dot']:.1e} | {r['setup_s']:.2f} |")
    if "paper" in results:
        p = results["paper"]
        m = p["pair"]["materialised (BLAS)"]
        print("\n| paper scale (19 det, 70x70, 560 bins, float32) | forward + adjoint (ms) "
              "| / materialised |")
        print("|---|---:|---:|")
        for k, v in p["pair"].items():
            print(f"| {k} | {v * 1e3:.1f} | {v / m:.2f} |")
        print(f"\nradon forward {p['radon_forward'] * 1e3:.1f} ms, adjoint "
              f"{p['radon_adjoint'] * 1e3:.1f} ms; setup: radon table {p['setup']['radon']:.2f} s "
              f"({p['table_mb']:.0f} MB) vs build_response {p['setup']['build_response']:.2f} s "
              f"({p['matrix_mb']:.0f} MB matrix)")
    if "wide" in results:
        w = results["wide"]
        print("\n| wide field (10^6 px, 61 det, 2000 bins) | value |")
        print("|---|---:|")
        for k in ("tolerance", "table", "n_q", "gemm", "setup_s", "forward_s", "adjoint_s",
                  "pair_s", "peak_gib_radon", "sampled_max_dP", "dense_product_s_est", "ratio",
                  "mlem_iter", "mlem_s", "mlem_peak_offsets_px", "peak_gib"):
            if k in w:
                v = w[k]
                print(f"| {k} | {v:.3g} |" if isinstance(v, float) else f"| {k} | {v} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=sorted(PARTS), default=None)
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--random", type=int, default=8, help="random geometries compared")
    ap.add_argument("--mlem-iter", type=int, default=200)
    ap.add_argument("--wide-tolerance", type=float, default=1e-3)
    ap.add_argument("--skip-wide", action="store_true")
    args = ap.parse_args()
    if args.part is not None:
        print(json.dumps(PARTS[args.part](args)))
        return
    names = ["accuracy", "paper"] + ([] if args.skip_wide else ["wide"])
    report({name: run_part(name, args) for name in names})


if __name__ == "__main__":
    main()
