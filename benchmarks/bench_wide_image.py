"""A converged default-method image of the 10^6-pixel wide field, coarse-to-fine (issue 24).

Run ``python benchmarks/bench_wide_image.py [--mlem-iter 200] [--skip-default-tol]``;
prints markdown tables whose numbers are recorded in docs/response.md and
docs/reconstruction.md (output: ``benchmarks/results/bench_wide_image.txt``).

The wide field of ``bench_radon.py``: 1000 x 1000 pixels of 6' (a 100 deg field), 61
detectors, 2000 bins, a = b = h = 1 cm lead at L = 114 cm, 662 keV, a Radon response at
tolerance 1e-3 (the tolerance MLEM's 1610 s were measured at); four point sources on their
pixels' centres, a known flat background of 2 per bin and detector, exposure 200 (the same
data as ``bench_radon.py``'s MLEM run, same seed).

* the pair: forward + adjoint of the full response, its parts (splat, detector stage,
  gather) and its floor from the arithmetic and the memory traffic, with the machine's
  rates measured in the same run (an sgemm's flop rate, a copy's bandwidth);
* ours: ``reconstruct(resp, counts, coarse=5)`` (the default method, NCAR, coarse-to-fine);
* MLEM at ``--mlem-iter`` iterations on the full response (timed in the same run);
* today's default method on the full response: too long to run here (2050 SGP iterations
  at one pair each), so its time is extrapolated from the measured pair and said so;
* the default tolerance 1e-4: setup + one pair.

Wall time and CPU (process) time are both given; the machine is shared, so the load is
quoted at each step.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numba
import numpy as np

from rotmod import DetectorArray, Instrument, Mask
from rotmod.reconstruction import Refinement, StoppingRule, reconstruct
from rotmod.reconstruction.algorithms import NCAR
from rotmod.response import RadonResponse, TimeBinning
from rotmod.response import radon as rmod
from rotmod.sky import SkyGrid

SOURCES = ((500, 500, 40.0), (520, 470, 25.0), (200, 800, 30.0), (850, 150, 20.0))


def load() -> float:
    return os.getloadavg()[0]


def timed(fn, *args, **kwargs):
    """``(fn(*args, **kwargs), wall s, cpu s, load at start)``."""
    ld = load()
    t, c = time.perf_counter(), time.process_time()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t, time.process_time() - c, ld


def machine_rates() -> dict:
    """Measured float32 sgemm rate (flop/s) and copy bandwidth (bytes/s read + written), per
    second of wall time and per second of CPU time (the load-insensitive rate of one core:
    a process that waits for a core uses none)."""
    a = np.ones((2000, 2000), np.float32)
    a @ a
    _, t, c, _ = timed(lambda: [a @ a for _ in range(5)])
    flops = 5 * 2 * 2000**3
    big = np.ones(50_000_000, np.float32)  # 200 MB
    dst = np.empty_like(big)
    np.copyto(dst, big)
    _, tb, cb, _ = timed(lambda: [np.copyto(dst, big) for _ in range(5)])
    nbytes = 5 * 2 * big.nbytes
    return {"flops": flops / t, "flops_cpu": flops / c, "bw": nbytes / tb, "bw_cpu": nbytes / cb}


def pair_parts(resp: RadonResponse, x: np.ndarray, y: np.ndarray) -> dict:
    """Wall time of the splat, detector stages and gather over every block."""
    f = resp._factors
    s = np.asarray(x, np.float64)[resp._perm]
    v = np.ascontiguousarray(s[:, None] * f.q_weights, dtype=resp.dtype)
    splat, gather = rmod._projection_kernels(f.n_q)
    yf = rmod.fold_half_turn(np.asarray(y, np.float64), resp.n_distinct)
    out = {"splat": 0.0, "detector": 0.0, "detector_adj": 0.0, "gather": 0.0}
    for t0, t1 in resp.blocks:
        sl = f.angles(t0, t1)
        n_ang = sl.stop - sl.start
        rr = np.zeros((n_ang, f.n_w, f.n_q), dtype=f.table.dtype)
        t = time.perf_counter()
        splat(f.tx, f.ty, v, f.cos_a[sl], f.sin_a[sl], f.k0, f.inv_dw, rr)
        t1_ = time.perf_counter()
        rmod._detect(f, sl, rr.reshape(n_ang, -1))
        t2_ = time.perf_counter()
        ya = np.repeat(np.ascontiguousarray(yf[:, t0:t1], dtype=f.table.dtype), f.n_sub, 1)
        t3_ = time.perf_counter()
        gg = rmod._detect_adjoint(f, sl, ya)
        t4_ = time.perf_counter()
        acc = np.zeros((f.tx.size, f.n_q), dtype=f.table.dtype)
        chunk = max(256, -(-f.tx.size // 64))
        t5_ = time.perf_counter()
        gather(f.tx, f.ty, f.cos_a[sl], f.sin_a[sl], f.k0, f.inv_dw,
               gg.reshape(n_ang, f.n_w, f.n_q), chunk, acc)
        t6_ = time.perf_counter()
        out["splat"] += t1_ - t
        out["detector"] += t2_ - t1_
        out["detector_adj"] += t4_ - t3_
        out["gather"] += t6_ - t5_
    return out


def pair_floor(resp: RadonResponse, rates: dict) -> dict:
    """The pair's arithmetic and memory traffic, and the CPU seconds they take at the
    measured per-core rates (a pair on two idle cores can take half that in wall time).
    Splat and gather: per (pixel, angle) the node and cubic weights (~14 flops) and ``4 R``
    multiply-adds; detector stage: two float32 GEMMs ``n_ang x K R x J``.  Memory: the
    pixels' coordinates and weights (``16 + 4 R`` bytes) streamed once per angle by today's
    loops (the floor of a loop order that does not tile angles), or once per product (the
    floor of an ideal tiling); the splatted rows ``n_ang K R`` written and read once."""
    f = resp._factors
    n_pix, n_ang, r = f.tx.size, f.cos_a.size, f.n_q
    j, kr = f.table.shape
    proj_flops = 2 * n_pix * n_ang * (14 + 8 * r)
    det_flops = 2 * 2 * n_ang * kr * j
    rows = 2 * 2 * n_ang * kr * 4
    per_angle = 2 * n_ang * n_pix * (16 + 4 * r) + rows
    once = 2 * n_pix * (16 + 4 * r) + rows + 2 * j * kr * 4
    flops = proj_flops + det_flops
    fr, bw = rates["flops_cpu"], rates["bw_cpu"]
    return {"flops": flops, "bytes_streamed": per_angle, "bytes_tiled": once,
            "cpu_flops": flops / fr, "cpu_streamed": per_angle / bw, "cpu_tiled": once / bw,
            "floor_cpu": max(flops / fr, once / bw),
            "floor_untiled_cpu": max(flops / fr, per_angle / bw)}


def offsets(img: np.ndarray) -> list[list[int]]:
    """Where the image peaks within 15 pixels of each source (the pair is 36 px apart)."""
    out = []
    for iy, ix, _ in SOURCES:
        win = img[iy - 15:iy + 16, ix - 15:ix + 16]
        dy, dx = np.unravel_index(int(np.argmax(win)), win.shape)
        out.append([int(dy) - 15, int(dx) - 15])
    return out


def fluxes(img: np.ndarray) -> list[float]:
    """Flux within 2 pixels of each source."""
    return [float(img[iy - 2:iy + 3, ix - 2:ix + 3].sum()) for iy, ix, _ in SOURCES]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--side", type=int, default=1000)
    ap.add_argument("--tolerance", type=float, default=1e-3)
    ap.add_argument("--factor", type=int, default=5)
    ap.add_argument("--coarse-iterations", type=int, default=Refinement.iterations,
                    help="SGP iterations of the coarse stage")
    ap.add_argument("--screen-iterations", type=int, default=Refinement.screen_iterations,
                    help="SGP iterations of the screening fits (0: the method every round)")
    ap.add_argument("--margin", type=int, default=Refinement.margin,
                    help="pixels around each pixel a check adds that join with it")
    ap.add_argument("--mlem-iter", type=int, default=200)
    ap.add_argument("--mlem-budget", type=float, default=1800.0,
                    help="seconds of MLEM at most (then extrapolated to --mlem-iter)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-default-tol", action="store_true")
    ap.add_argument("--skip-image", action="store_true",
                    help="only the pairs and their floors (no reconstruction)")
    ap.add_argument("--small", action="store_true",
                    help="instead: coarse-to-fine against the full solve on a field where both "
                         "run (100 x 100 pixels, 500 bins)")
    ap.add_argument("--json", default="")
    args = ap.parse_args()
    if args.small:
        small(args)
        return
    inst = Instrument(Mask(1.0, 1.0, 1.0, 114.0), DetectorArray.hexagonal(1.0, rings=4))
    grid = SkyGrid((args.side, args.side), 0.1)
    tb = TimeBinning(2000)
    print(f"# Wide-field image: {platform.machine()}, {numba.get_num_threads()} numba threads, "
          f"load {load():.2f} at start\n")
    res: dict = {"load_start": load()}
    rates = machine_rates()
    res.update(sgemm_gflops=rates["flops"] / 1e9, copy_gbs=rates["bw"] / 1e9,
               sgemm_gflops_cpu=rates["flops_cpu"] / 1e9, copy_gbs_cpu=rates["bw_cpu"] / 1e9)

    resp, res["setup_s"], res["setup_cpu"], _ = timed(
        lambda: RadonResponse(inst, grid, tb, 662.0, tolerance=args.tolerance))
    rng = np.random.default_rng(1)
    x = rng.random(grid.size).astype(np.float32)
    y = rng.random((resp.n_det, resp.n_time)).astype(np.float32)
    resp.forward(x)
    resp.adjoint(y)
    pairs = [timed(lambda: (resp.forward(x), resp.adjoint(y))) for _ in range(args.repeat)]
    res["pair_s"] = float(np.median([p[1] for p in pairs]))
    res["pair_cpu"] = float(np.median([p[2] for p in pairs]))
    res["pair_load"] = float(np.median([p[3] for p in pairs]))
    res["parts"] = pair_parts(resp, x, y)
    res["floor"] = pair_floor(resp, rates)
    res["table"] = [int(resp.table.shape[0]), resp._factors.n_w, resp._factors.n_q]
    print(json.dumps(res, default=float), flush=True)

    truth = np.zeros(grid.shape)
    for iy, ix, flux in SOURCES:
        truth[iy, ix] = flux
    expo = 200.0
    counts = rng.poisson(expo * (resp.forward(truth.ravel()).astype(np.float64) + 2.0))

    if not args.skip_image:
        image_part(args, res, resp, grid, counts, expo)
    if not args.skip_default_tol:
        r4, res["tol4_setup_s"], res["tol4_setup_cpu"], res["tol4_load"] = timed(
            lambda: RadonResponse(inst, grid, tb, 662.0))
        res["tol4_table"] = [int(r4.table.shape[0]), r4._factors.n_w, r4._factors.n_q]
        r4.forward(x)
        r4.adjoint(y)
        p4 = [timed(lambda: (r4.forward(x), r4.adjoint(y))) for _ in range(args.repeat)]
        res["tol4_pair_s"] = float(np.median([p[1] for p in p4]))
        res["tol4_pair_cpu"] = float(np.median([p[2] for p in p4]))
        res["tol4_parts"] = pair_parts(r4, x, y)
        res["tol4_floor"] = pair_floor(r4, rates)
    res["load_end"] = load()
    report(res)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(res, fh, indent=1, default=float)


def image_part(args, res: dict, resp: RadonResponse, grid: SkyGrid, counts: np.ndarray,
               expo: float) -> None:
    """Ours (coarse-to-fine), today's default extrapolated, MLEM."""
    ours, res["ours_s"], res["ours_cpu"], res["ours_load"] = timed(lambda: reconstruct(
        resp, counts, exposure=expo, background=2.0, seed=1,
        coarse=Refinement(factor=args.factor, iterations=args.coarse_iterations,
                          screen_iterations=args.screen_iterations, margin=args.margin)))
    ex = ours.extras
    res["ours"] = {"offsets": offsets(ours.image), "fluxes": fluxes(ours.image),
                   "n_iter": ours.n_iter, "stop": ours.stop_reason,
                   "deviance": ours.deviance, "chi2_dof": ours.chi2_dof,
                   "coarse_s": ex["coarse_s"], "rounds": ex["rounds"],
                   "support": int(ex["support"].sum()),
                   "max_ts_outside": ex["max_ts_outside"],
                   "layer_iterations": ex.get("layer_iterations"),
                   "refit_iterations": ex.get("refit_iterations")}
    res["load_after_ours"] = load()
    print(json.dumps(res, indent=1, default=float), flush=True)

    # Today's default on the full response: extrapolated (SGP iterations x pair).
    max_sgp = (NCAR.default_stopping.max_iter
               + (2 * NCAR.defaults["n_layers"] + 1) * NCAR.defaults["layer_iter"])
    res["default_full_iter"] = max_sgp
    res["default_full_s_extrap"] = max_sgp * res["pair_s"]
    res["default_full_cpu_extrap"] = max_sgp * res["pair_cpu"]

    # MLEM on the full response, in this run: up to --mlem-iter iterations or --mlem-budget
    # seconds, whichever comes first; if the budget stops it, the time of --mlem-iter is
    # extrapolated linearly from the iterations done (every iteration is one pair).
    if args.mlem_iter:
        rule = StoppingRule(max_iter=args.mlem_iter, chi2_dof=None, rel_tol=None)
        t_mlem = time.perf_counter()

        def budget(solver, it):
            return time.perf_counter() - t_mlem > args.mlem_budget

        mlem, res["mlem_s"], res["mlem_cpu"], res["mlem_load"] = timed(lambda: reconstruct(
            resp, counts, "mlem", exposure=expo, background=2.0, stopping=rule,
            callbacks=[budget]))
        res["mlem"] = {"offsets": offsets(mlem.image), "fluxes": fluxes(mlem.image),
                       "n_iter": mlem.n_iter, "deviance": mlem.deviance,
                       "chi2_dof": mlem.chi2_dof}
        scale = args.mlem_iter / max(mlem.n_iter, 1)
        res["mlem_iter_target"] = args.mlem_iter
        res["mlem_full_s"] = res["mlem_s"] * scale
        res["mlem_full_cpu"] = res["mlem_cpu"] * scale
        res["mlem_extrapolated"] = mlem.n_iter < args.mlem_iter
        res["load_after_mlem"] = load()
        print(json.dumps({k: res[k] for k in res if k.startswith("mlem")}, default=float),
              flush=True)


def small(args) -> None:
    """Coarse-to-fine against the full-resolution solve, the same data and method."""
    inst = Instrument(Mask(1.0, 1.0, 1.0, 114.0), DetectorArray.hexagonal(1.0, rings=4))
    grid = SkyGrid((100, 100), 0.1)
    resp = RadonResponse(inst, grid, TimeBinning(500), 662.0, tolerance=args.tolerance)
    truth = np.zeros(grid.shape)
    srcs = ((50, 50, 40.0), (52, 45, 25.0), (20, 80, 30.0), (85, 15, 20.0))
    for iy, ix, flux in srcs:
        truth[iy, ix] = flux
    rng = np.random.default_rng(2)
    counts = rng.poisson(200.0 * (resp.forward(truth.ravel()).astype(np.float64) + 2.0))
    print(f"# Coarse-to-fine vs full solve: 100 x 100 x 0.1 deg, 61 detectors, 500 bins, "
          f"tolerance {args.tolerance:g}, load {load():.2f}\n")
    print("| method | route | wall | CPU | deviance | log L - log L(full) | max abs image diff "
          "| flux at the 4 sources (truth 40/25/30/20) | peaks on their pixels | support |\n"
          "|---|---|---:|---:|---:|---:|---:|---|---|---:|")
    for method, extra in (("ncar", {"seed": 1}), ("sgp", {})):
        full, tf, cf, _ = timed(reconstruct, resp, counts, method, exposure=200.0,
                                background=2.0, **extra)
        for cut in (25.0, 0.0):
            c2f, tc, cc, _ = timed(reconstruct, resp, counts, method, exposure=200.0,
                                   background=2.0,
                                   coarse=Refinement(factor=args.factor, ts_cut=cut), **extra)
            for label, r, t, c in (("full", full, tf, cf),
                                   (f"coarse-to-fine, ts_cut {cut:g}", c2f, tc, cc)):
                if label == "full" and cut == 0.0:
                    continue
                img = r.image
                on = all(np.unravel_index(int(np.argmax(img[iy - 3:iy + 4, ix - 3:ix + 4])),
                                          (7, 7)) == (3, 3) for iy, ix, _ in srcs)
                flx = [round(float(img[iy - 1:iy + 2, ix - 1:ix + 2].sum()), 1)
                       for iy, ix, _ in srcs]
                sup = int(r.extras["support"].sum()) if "support" in r.extras else grid.size
                print(f"| {method} | {label} | {t:.0f} s | {c:.0f} s | {r.deviance:.1f} | "
                      f"{-(r.deviance - full.deviance) / 2:+.2f} | "
                      f"{np.abs(img - full.image).max():.3f} | {flx} | {on} | {sup} |",
                      flush=True)


def floor_rows(r: dict, fl: dict, pair_cpu: float) -> str:
    return (f"| floor: arithmetic {fl['flops'] / 1e9:.0f} Gflop at "
            f"{r['sgemm_gflops_cpu']:.0f} Gflop per CPU-s (sgemm, measured) | | "
            f"{fl['cpu_flops']:.2f} s |\n"
            f"| floor: memory, coordinates once per angle (today's loop order) "
            f"{fl['bytes_streamed'] / 1e9:.0f} GB at {r['copy_gbs_cpu']:.0f} GB per CPU-s "
            f"(copy, measured) | | {fl['cpu_streamed']:.2f} s |\n"
            f"| floor: memory, ideal tiling {fl['bytes_tiled'] / 1e9:.2f} GB | | "
            f"{fl['cpu_tiled']:.2f} s |\n"
            f"| pair CPU / floor (ideal) / floor (today's loop order) | | "
            f"{pair_cpu / fl['floor_cpu']:.1f}x / {pair_cpu / fl['floor_untiled_cpu']:.1f}x |\n")


def report(r: dict) -> None:
    pa = r["parts"]
    print(f"| wide field, tolerance 1e-3 (table {r['table']}) | wall | CPU |\n|---|---:|---:|\n"
          f"| setup | {r['setup_s']:.1f} s | {r['setup_cpu']:.1f} s |\n"
          f"| pair, median (load {r['pair_load']:.1f}) | {r['pair_s']:.2f} s | "
          f"{r['pair_cpu']:.2f} s |\n"
          f"| splat / detector / detector adjoint / gather | {pa['splat']:.2f} / "
          f"{pa['detector']:.2f} / {pa['detector_adj']:.2f} / {pa['gather']:.2f} s | |\n"
          + floor_rows(r, r["floor"], r["pair_cpu"]))
    if "ours" in r:
        o = r["ours"]
        print("| image (4 sources, 10^6 px) | wall | CPU | load | iterations | source offsets "
              "(px) | fluxes within 2 px (truth 40/25/30/20) | deviance |\n"
              "|---|---:|---:|---:|---:|---|---|---:|")
        print(f"| **default (ncar), coarse-to-fine** | **{r['ours_s']:.0f} s** | "
              f"{r['ours_cpu']:.0f} s | {r['ours_load']:.1f} | {o['n_iter']} + layers "
              f"{o['layer_iterations']} + refit {o['refit_iterations']} | {o['offsets']} | "
              f"{[round(v, 1) for v in o['fluxes']]} | {o['deviance']:.0f} |")
    if "mlem_s" in r:
        m = r["mlem"]
        ext = " (**extrapolated** from the iterations run)" if r["mlem_extrapolated"] else ""
        print(f"| MLEM, full response, {m['n_iter']} iterations run | {r['mlem_s']:.0f} s | "
              f"{r['mlem_cpu']:.0f} s | {r['mlem_load']:.1f} | {m['n_iter']} | {m['offsets']} | "
              f"{[round(v, 1) for v in m['fluxes']]} | {m['deviance']:.0f} |")
        print(f"| MLEM, {r['mlem_iter_target']} iterations{ext} | {r['mlem_full_s']:.0f} s | "
              f"{r['mlem_full_cpu']:.0f} s | | | | | |")
    if "ours" in r:
        print(f"| default (ncar), full response (**extrapolated**: {r['default_full_iter']} SGP "
              f"iterations x the measured pair, not run) | {r['default_full_s_extrap']:.0f} s | "
              f"{r['default_full_cpu_extrap']:.0f} s | | {r['default_full_iter']} | | | |\n")
        print(f"ratio extrapolated full default / ours: "
              f"{r['default_full_s_extrap'] / r['ours_s']:.0f}x wall, "
              f"{r['default_full_cpu_extrap'] / r['ours_cpu']:.0f}x CPU")
        if "mlem_s" in r:
            print(f"ratio MLEM-{r['mlem_iter_target']} / ours: "
                  f"{r['mlem_full_s'] / r['ours_s']:.1f}x wall, "
                  f"{r['mlem_full_cpu'] / r['ours_cpu']:.1f}x CPU")
        o = r["ours"]
        print(f"\ncoarse stage {o['coarse_s']:.1f} s; support {o['support']} px; rounds "
              f"{o['rounds']}; largest score TS left outside {o['max_ts_outside']:.2f}\n")
    if "tol4_setup_s" in r:
        p4 = r["tol4_parts"]
        print(f"| default tolerance 1e-4 (table {r['tol4_table']}, load {r['tol4_load']:.1f}) "
              f"| wall | CPU |\n|---|---:|---:|\n"
              f"| setup | {r['tol4_setup_s']:.1f} s | {r['tol4_setup_cpu']:.1f} s |\n"
              f"| pair (median) | {r['tol4_pair_s']:.1f} s | {r['tol4_pair_cpu']:.1f} s |\n"
              f"| setup + pair (target <= 30 s) | {r['tol4_setup_s'] + r['tol4_pair_s']:.1f} s "
              f"| {r['tol4_setup_cpu'] + r['tol4_pair_cpu']:.1f} s |\n"
              f"| splat / detector / detector adjoint / gather | {p4['splat']:.2f} / "
              f"{p4['detector']:.2f} / {p4['detector_adj']:.2f} / {p4['gather']:.2f} s | |\n"
              + floor_rows(r, r["tol4_floor"], r["tol4_pair_cpu"]))
    print(f"load at end {r['load_end']:.2f}")


if __name__ == "__main__":
    main()
