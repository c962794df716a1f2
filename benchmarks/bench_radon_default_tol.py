"""The wide field at the default tolerance: setup + pair, before and after restricting the
BLAS detector stage to the used ``w`` range (issue 24).

Run ``python benchmarks/bench_radon_default_tol.py [--tolerances 1e-4 1e-3] [--repeat 3]``;
prints a markdown table recorded in docs/response.md (output:
``benchmarks/results/bench_radon_default_tol.txt`` and ``.json``).

The wide field of ``bench_radon.py`` / ``bench_wide_image.py`` (1000 x 1000 pixels of 6',
61 detectors, 2000 bins, 662 keV).  Per tolerance: the setup once (the restriction does not
change it), then "full" (the BLAS stage over every column of the table: the operator's
used ranges set to the whole row, which is exactly the product before the change) and
"restricted" (today's) timed alternately, ``--repeat`` pairs each, medians of wall and CPU
(process) time; the detector stages alone (forward and adjoint, every block) the same way.
The paper-scale pair (``SkyGrid.paper()``, 560 bins) is timed too.  The machine is shared:
the load is quoted at each step.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np
from bench_radon import wide_instrument
from bench_wide_image import load, timed

from rotmod.io import load_instrument
from rotmod.response import RadonResponse, TimeBinning
from rotmod.response import radon as rmod
from rotmod.sky import SkyGrid

OUT = Path(__file__).parent / "results" / "bench_radon_default_tol"


def full_range(resp: RadonResponse) -> RadonResponse:
    """``resp`` with every angle's used range the whole row: the BLAS stage as it was."""
    f = resp._factors
    resp._factors = dataclasses.replace(f, k_lo=np.zeros_like(f.k_lo),
                                        k_hi=np.full_like(f.k_hi, f.table.shape[1]))
    return resp


def detector_stages(resp: RadonResponse, rng: np.random.Generator) -> tuple[float, float]:
    """CPU seconds of the forward and adjoint detector stages over every block (random
    splat rows, zero outside each angle's true used range)."""
    f = resp._factors
    t_f = t_a = 0.0
    k = np.arange(f.table.shape[1])
    for t0, t1 in resp.blocks:
        sl = f.angles(t0, t1)
        n_ang = sl.stop - sl.start
        flat = rng.random((n_ang, k.size), dtype=np.float32)
        flat[(k < f.k_lo[sl, None]) | (k >= f.k_hi[sl, None])] = 0.0
        ya = rng.random((resp.n_det, n_ang), dtype=np.float32)
        c = time.process_time()
        rmod._detect(f, sl, flat)
        t_f += time.process_time() - c
        c = time.process_time()
        rmod._detect_adjoint(f, sl, ya)
        t_a += time.process_time() - c
    return t_f, t_a


def wide(tol: float, repeat: int) -> dict:
    grid = SkyGrid((1000, 1000), 0.1)
    tb = TimeBinning(2000)
    resp, wall, cpu, ld = timed(RadonResponse, wide_instrument(), grid, tb, 662.0,
                                tolerance=tol)
    f = resp._factors
    frac = float(np.mean(f.k_hi - f.k_lo)) / f.table.shape[1]
    spans = [rmod._used_range(f, f.angles(*b)) for b in resp.blocks]
    block_frac = float(np.mean([hi - lo for lo, hi in spans])) / f.table.shape[1]
    out = {"tolerance": tol, "table": [int(f.table.shape[0]), f.n_w, f.n_q], "gemm": f.gemm,
           "blocks": len(resp.blocks), "used_fraction_angle": frac,
           "used_fraction_block": block_frac, "setup_wall": wall, "setup_cpu": cpu,
           "setup_load": ld}
    print(f"tol {tol:g}: setup {wall:.1f} s wall / {cpu:.1f} s CPU (load {ld:.1f}), "
          f"table {out['table']}, used {frac:.3f} (angle) / {block_frac:.3f} (block)",
          flush=True)
    rng = np.random.default_rng(1)
    x = rng.random(grid.size).astype(np.float32)
    y = rng.random((resp.n_det, resp.n_time)).astype(np.float32)
    restricted = resp._factors
    old = full_range(resp)._factors
    resp.forward(x)  # warm-up (numba cache load)
    runs: dict = {"full": [], "restricted": []}
    det: dict = {"full": [], "restricted": []}
    results = {}
    for _ in range(repeat):
        for name, fac in (("full", old), ("restricted", restricted)):
            resp._factors = fac
            ld = load()
            w, c = time.perf_counter(), time.process_time()
            fw = resp.forward(x)
            ad = resp.adjoint(y)
            runs[name].append((time.perf_counter() - w, time.process_time() - c, ld))
            results[name] = (fw, ad)
            det[name].append(detector_stages(resp, np.random.default_rng(2)))
            print(f"  {name}: pair {runs[name][-1][0]:.1f} s wall / {runs[name][-1][1]:.1f} "
                  f"s CPU (load {ld:.1f}); detector stages CPU {det[name][-1][0]:.2f} / "
                  f"{det[name][-1][1]:.2f} s", flush=True)
    (f_full, a_full), (f_res, a_res) = results["full"], results["restricted"]
    out["max_rel_diff_forward"] = float(np.max(np.abs(f_res - f_full)) / np.max(np.abs(f_full)))
    out["max_rel_diff_adjoint"] = float(np.max(np.abs(a_res - a_full)) / np.max(np.abs(a_full)))
    for name in runs:
        r = np.array(runs[name])
        d = np.array(det[name])
        out[name] = {"pair_wall": float(np.median(r[:, 0])), "pair_cpu": float(np.median(r[:, 1])),
                     "load": [float(r[:, 2].min()), float(r[:, 2].max())],
                     "det_fwd_cpu": float(np.median(d[:, 0])),
                     "det_adj_cpu": float(np.median(d[:, 1])), "runs": r.tolist()}
    return out


def rows_probe(tol: float, n_blocks: int) -> dict:
    """CPU seconds of the rows path's detector stages (forward + adjoint) on the wide field,
    timed on ``n_blocks`` blocks and scaled to all: the rows kernels run on this table with
    two taps (a row of the same length as the rows path's half-step linear table, and the
    same two rows read per detector and angle; only the table's row count differs)."""
    resp = RadonResponse(wide_instrument(), SkyGrid((1000, 1000), 0.1), TimeBinning(2000),
                         662.0, tolerance=tol)
    f = resp._factors
    jx, ax = np.ascontiguousarray(f.jx[:, :, :2]), np.ascontiguousarray(f.ax[:, :, :2])
    rng = np.random.default_rng(3)
    t_f = t_a = 0.0
    for i, (t0, t1) in enumerate(resp.blocks[:n_blocks + 1]):
        sl = f.angles(t0, t1)
        n_ang = sl.stop - sl.start
        flat = rng.random((n_ang, f.table.shape[1]), dtype=np.float32)
        ya = rng.random((resp.n_det, n_ang), dtype=np.float32)
        out = np.empty((resp.n_det, n_ang), dtype=np.float32)
        gg = np.zeros_like(flat)
        args = (jx[:, sl], ax[:, sl])
        c = time.process_time()
        rmod._rows_forward(f.table, flat, *args, f.k_lo[sl], f.k_hi[sl], out)
        t_f += time.process_time() - c
        c = time.process_time()
        rmod._rows_adjoint(f.table, ya, *args, f.k_lo[sl], f.k_hi[sl], gg)
        t_a += time.process_time() - c
        if i == 0:  # the first block is a warm-up (numba cache load), not timed
            t_f = t_a = 0.0
    scale = len(resp.blocks) / n_blocks
    res = {"tolerance": tol, "blocks_timed": n_blocks, "blocks": len(resp.blocks),
           "rows_fwd_cpu": t_f * scale, "rows_adj_cpu": t_a * scale, "load": load()}
    print(res, flush=True)
    return res


def paper(repeat: int) -> dict:
    inst = load_instrument("prototype")
    grid = SkyGrid.paper()
    tb = TimeBinning(560)
    resp = RadonResponse(inst, grid, tb, 662.0)
    rng = np.random.default_rng(0)
    x = rng.random(grid.size).astype(np.float32)
    y = rng.random((resp.n_det, resp.n_time)).astype(np.float32)
    resp.forward(x), resp.adjoint(y)
    ts = []
    for _ in range(repeat):
        _, w, c, ld = timed(lambda: (resp.forward(x), resp.adjoint(y)))
        ts.append((w, c, ld))
    t = np.array(ts)
    return {"gemm": resp._factors.gemm, "pair_wall_ms": 1e3 * float(np.median(t[:, 0])),
            "pair_cpu_ms": 1e3 * float(np.median(t[:, 1])), "load": float(np.median(t[:, 2]))}


def report(res: dict) -> str:
    lines = [f"load at start {res['load_start']:.2f}, at end {res['load_end']:.2f}; "
             f"{os.cpu_count()} cores, OPENBLAS_NUM_THREADS="
             f"{os.environ.get('OPENBLAS_NUM_THREADS', '-')}", "",
             "| tolerance | table (J x K x R) | used fraction (angle / block) | setup wall / CPU "
             "| pair full: wall / CPU | pair restricted: wall / CPU | detector stages CPU "
             "fwd+adj: full / restricted | setup + pair (restricted) wall / CPU | load |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for w in res["wide"]:
        fu, re_ = w["full"], w["restricted"]
        j, k, r = w["table"]
        lo = min(fu["load"][0], re_["load"][0])
        hi = max(fu["load"][1], re_["load"][1])
        lines.append(
            f"| {w['tolerance']:g} | {j} x {k} x {r} | {w['used_fraction_angle']:.3f} / "
            f"{w['used_fraction_block']:.3f} | {w['setup_wall']:.1f} / {w['setup_cpu']:.1f} s "
            f"| {fu['pair_wall']:.1f} / {fu['pair_cpu']:.1f} s "
            f"| {re_['pair_wall']:.1f} / {re_['pair_cpu']:.1f} s "
            f"| {fu['det_fwd_cpu'] + fu['det_adj_cpu']:.1f} / "
            f"{re_['det_fwd_cpu'] + re_['det_adj_cpu']:.1f} s "
            f"| {w['setup_wall'] + re_['pair_wall']:.1f} / "
            f"{w['setup_cpu'] + re_['pair_cpu']:.1f} s | {lo:.1f}-{hi:.1f} |")
        lines.append(f"<!-- tol {w['tolerance']:g}: restricted vs full, max rel diff forward "
                     f"{w['max_rel_diff_forward']:.2e}, adjoint "
                     f"{w['max_rel_diff_adjoint']:.2e} -->")
    p = res.get("paper")
    if p:
        lines += ["", f"paper-scale pair (gemm={p['gemm']}): {p['pair_wall_ms']:.1f} ms wall / "
                      f"{p['pair_cpu_ms']:.1f} ms CPU, median, load {p['load']:.1f}"]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tolerances", type=float, nargs="+", default=[1e-4, 1e-3])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--paper-repeat", type=int, default=9)
    ap.add_argument("--rows-probe", type=int, default=0, metavar="N_BLOCKS",
                    help="only time the rows path's detector stages at the first tolerance "
                         "on N_BLOCKS blocks (results/bench_radon_default_tol_rows.json)")
    args = ap.parse_args()
    if args.rows_probe:
        res = rows_probe(args.tolerances[0], args.rows_probe)
        OUT.with_name(OUT.name + "_rows.json").write_text(json.dumps(res, indent=1))
        return
    res: dict = {"load_start": load(), "wide": []}
    res["paper"] = paper(args.paper_repeat)
    print(res["paper"], flush=True)
    for tol in args.tolerances:
        res["wide"].append(wide(tol, args.repeat))
        OUT.with_suffix(".json").write_text(json.dumps(res, indent=1))
    res["load_end"] = load()
    OUT.with_suffix(".json").write_text(json.dumps(res, indent=1))
    text = report(res)
    OUT.with_suffix(".txt").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
