"""Reconstruction quality and speed of every method on the issue-11 scenarios, side by side.

Run: ``python benchmarks/bench_reconstruction.py [--scenarios thin,proto,field] [--quick]``.

Data: Poisson draws of the *exact* profile model (360 bin-averaged time bins, as
``TimeBinning(360, "average")``) computed separately for each source with 16 sub-samples
per bin, while the reconstruction's response uses the library default (exact model, 4
sub-samples per bin, float32); the background is flat and known (given to every method).

Scenarios (counts printed with each table):

* ``thin``: 0.5 cm lead at 662 keV (sigma 0.103 cm2/g), a = b = c = 4 cm, L = 100 cm
  (b/L = 2.29 deg), 19 detectors; two equal sources 1.2 deg apart (and the separation
  sweep 1.8 ... 0.6 deg), flat background counts = the sources' counts.
* ``proto``: the ``prototype`` preset (19 x 3.8 cm, b/L = 1.9 deg, 2 cm lead) at
  122 keV; two equal sources of 60 /s at 35' and 30' (sweep 35' ... 10'), background
  counts = the sources' counts (8.3e6 counts in all).
* ``field``: ``SkyGrid.paper()`` (14 deg field, 70 x 70 pixels of 12'), the paper's mask
  (2 cm lead, 662 keV) over 19 detectors of 4 cm; three sources of rates 10, 5 and 3 /s
  across the field, background counts = the sources' counts.
"""

from __future__ import annotations

import argparse
import logging
import os
import time

import numpy as np

from rotmod.geometry import DetectorArray, Instrument
from rotmod.materials import PAPER_SIGMA_662
from rotmod.reconstruction import reconstruct
from rotmod.reconstruction.api import DEFAULT_METHOD
from rotmod.reconstruction.metrics import evaluate
from rotmod.response import TimeBinning, build_response
from rotmod.sky.grid import SkyGrid

log = logging.getLogger("bench_reconstruction")

N_BINS, EXPOSURE_PER_BIN = 360, 10.0  # 3600 s observations, whole turns
PROTO_FLUX = [60.0, 60.0]

METHODS: list[tuple[str, str, dict]] = [
    ("backprojection", "backprojection", {}),
    ("mlem", "mlem", {}),
    ("mlem 1e4", "mlem", {"max_iter": 10_000, "rel_tol": None, "chi2_dof": None}),
    ("mart", "mart", {}),
    ("sirt", "sirt", {}),
    ("osem", "osem", {}),
    ("sgp", "sgp", {}),
    ("sparse", "sparse", {}),
    ("ncar", "ncar", {}),
    ("ncar (sirt core)", "ncar", {"core": "sirt"}),
]


def thin_instrument() -> Instrument:
    one = Instrument.paper(h=0.5, sigma=PAPER_SIGMA_662)
    return Instrument(one.mask, DetectorArray.hexagonal(4.0, rings=2), one.rotation_period)


def field_instrument() -> Instrument:
    one = Instrument.paper(h=2.0, sigma=PAPER_SIGMA_662)
    return Instrument(one.mask, DetectorArray.hexagonal(4.0, rings=2), one.rotation_period)


def simulate(inst, grid, xy, flux, energy, seed):
    """Counts (n_det, n_bins): exact model per source (16 sub-samples), flat background."""
    tb = TimeBinning(N_BINS, "average", n_sub=16)
    src = np.zeros((len(inst.detectors), N_BINS))
    for (x, y), f in zip(xy, flux, strict=True):
        one = SkyGrid((1, 1), grid.pixel_size, (x, y))
        r = build_response(inst, one, tb, model="exact", energy=energy, dtype=np.float64)
        src += EXPOSURE_PER_BIN * f * r.forward(np.ones(1))
    bkg_rate = src.sum() / src.size / EXPOSURE_PER_BIN  # background counts = source counts
    rng = np.random.default_rng(seed)
    y = rng.poisson(src + EXPOSURE_PER_BIN * bkg_rate).astype(float)
    th, ph = grid.from_tangent(np.array([p[0] for p in xy]), np.array([p[1] for p in xy]))
    return y, bkg_rate, (th, ph)


def run_methods(resp, y, bkg, grid, sources, flux, radius, methods, label, rows, seed=3):
    for name, method, kw in methods:
        t0 = time.perf_counter()
        res = reconstruct(resp, y, method, exposure=EXPOSURE_PER_BIN, background=bkg,
                          seed=seed, **kw)
        dt = time.perf_counter() - t0
        m = evaluate(res, grid, sources, true_flux=flux, radius=radius)
        rows.append((label, name, m, res.n_iter, dt, res.params.get("lambda")))
        log.info("%s %-18s loc %.3f spur/weakest %.2f dip %s iters %d %.2f s", label, name,
                 m["loc_err_max"], m["spurious_weakest"], f"{m.get('dip', np.nan):.2f}",
                 res.n_iter, dt)


def table(rows, title) -> str:
    out = [f"\n### {title}\n", "| case | method | loc err (deg) | spurious/weakest | dip | "
           "flux | chi2/dof | iters | time (s) |", "|---|---|---|---|---|---|---|---|---|"]
    for label, name, m, it, dt, _ in rows:
        out.append(
            f"| {label} | {name} | {m['loc_err_max']:.3f} | {m['spurious_weakest']:.2f} | "
            f"{m.get('dip', float('nan')):.2f} | {m['flux_ratio']:.2f} | {m['chi2_dof']:.3f} |"
            f" {it} | {dt:.2f} |"
        )
    return "\n".join(out)


def pair(inst, energy, pix, n_pix, seps, flux, methods, label_fmt, radius_frac=0.45):
    rows = []
    grid = SkyGrid((n_pix, n_pix), pix, (1.0, 0.0))
    t0 = time.perf_counter()
    resp = build_response(inst, grid, TimeBinning(N_BINS, "average"), energy=energy)
    log.info("response %s in %.1f s", resp, time.perf_counter() - t0)
    counts = []
    for k, sep in enumerate(seps):
        # Sources on pixel centres: y = -floor(n/2) pix and the rest of the separation.
        n_sep = round(sep / pix)
        y0 = -(n_sep // 2) * pix
        xy = [(1.0, y0), (1.0, y0 + n_sep * pix)]
        y, bkg, src = simulate(inst, grid, xy, flux, energy, seed=10 + k)
        counts.append(f"{label_fmt(sep)}: {y.sum():.3g} counts (background {bkg:.2f} /s "
                      f"per detector)")
        run_methods(resp, y, bkg, grid, src, flux, max(radius_frac * sep, pix), methods,
                    label_fmt(sep), rows)
    return rows, counts, resp, grid


def dip_vs_separation(rows, prefix: str, pix: float) -> str:
    """Dip per method (rows) and separation (columns); ``(x)`` marks a failed criterion:
    a peak more than one pixel off or a spurious peak >= 20 % of the weakest source."""
    labels = list(dict.fromkeys(label for label, *_ in rows if label.startswith(prefix)))
    names = list(dict.fromkeys(name for _, name, *_ in rows))
    by = {(label, name): m for label, name, m, *_ in rows}
    out = ["| method | " + " | ".join(labels) + " |", "|---" * (len(labels) + 1) + "|"]
    for name in names:
        cells = []
        for label in labels:
            m = by.get((label, name))
            if m is None:
                cells.append("")
                continue
            bad = m["loc_err_max"] > pix * (1 + 1e-6) or m["spurious_weakest"] >= 0.2
            cells.append(f"{m.get('dip', float('nan')):.2f}" + (" (x)" if bad else ""))
        out.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def versus_mlem(rows) -> str:
    """Rows where the default method is worse than MLEM (500 iterations) on localisation
    (by more than 0.01 deg) or on the spurious level (by more than 0.02)."""
    by = {(label, name): m for label, name, m, *_ in rows}
    worse = []
    for (label, name), m in by.items():
        if name != DEFAULT_METHOD or (label, "mlem") not in by:
            continue
        ref = by[(label, "mlem")]
        if m["loc_err_max"] > ref["loc_err_max"] + 0.01 or (
            m["spurious_weakest"] > ref["spurious_weakest"] + 0.02
        ):
            worse.append(f"{label}: loc {m['loc_err_max']:.3f} vs {ref['loc_err_max']:.3f}, "
                         f"spurious {m['spurious_weakest']:.2f} vs {ref['spurious_weakest']:.2f}")
    return "default vs MLEM, worse on localisation or spurious peaks: " + (
        "; ".join(worse) if worse else "none")


def seeds_table(n_seeds: int) -> str:
    """The default method on the required pairs, over independent noise realisations."""
    from rotmod.io import load_instrument

    out = [f"\n### {DEFAULT_METHOD} over {n_seeds} noise realisations\n",
           "| case | dip (median, max) | loc err max (deg) | spurious/weakest max | "
           "resolved | time median (s) |", "|---|---|---|---|---|---|"]
    cases = [("thin 1.2 deg", thin_instrument(), 662.0, 0.3, 1.2, [10.0, 10.0]),
             ("proto 35'", load_instrument("prototype"), 122.0, 5 / 60, 35 / 60, PROTO_FLUX),
             ("proto 30'", load_instrument("prototype"), 122.0, 5 / 60, 30 / 60, PROTO_FLUX)]
    for label, inst, energy, pix, sep, flux in cases:
        grid = SkyGrid((31, 31), pix, (1.0, 0.0))
        resp = build_response(inst, grid, TimeBinning(N_BINS, "average"), energy=energy)
        n_sep = round(sep / pix)
        y0 = -(n_sep // 2) * pix
        xy = [(1.0, y0), (1.0, y0 + n_sep * pix)]
        dips, locs, spurs, times, ok = [], [], [], [], 0
        for seed in range(n_seeds):
            y, bkg, src = simulate(inst, grid, xy, flux, energy, seed=100 + seed)
            t0 = time.perf_counter()
            res = reconstruct(resp, y, exposure=EXPOSURE_PER_BIN, background=bkg, seed=seed)
            times.append(time.perf_counter() - t0)
            m = evaluate(res, grid, src, true_flux=flux, radius=0.45 * sep)
            dips.append(m["dip"])
            locs.append(m["loc_err_max"])
            spurs.append(m["spurious_weakest"])
            # "Each peak within one pixel": centroid at most one pixel from its source.
            ok += (m["dip"] < 0.8 and m["loc_err_max"] <= pix * (1 + 1e-6)
                   and m["spurious_weakest"] < 0.2)
            log.info("%s seed %d: %s", label, seed, {k: round(m[k], 3) for k in
                                                     ("dip", "loc_err_max", "spurious_weakest")})
        out.append(f"| {label} | {np.median(dips):.2f}, {np.max(dips):.2f} | "
                   f"{np.max(locs):.3f} | {np.max(spurs):.2f} | {ok}/{n_seeds} | "
                   f"{np.median(times):.2f} |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scenarios", default="thin,proto,field")
    ap.add_argument("--quick", action="store_true", help="only the required separations")
    ap.add_argument("--out", default=None, help="also write the tables to this file")
    ap.add_argument("--seeds", type=int, default=5,
                    help="noise realisations for the default method's pair table (0: skip)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    print(f"default method: {DEFAULT_METHOD}; load average {os.getloadavg()}; "
          f"{os.cpu_count()} cores")
    chunks = []
    every: list = []
    flux2 = [10.0, 10.0]
    names = set(args.scenarios.split(","))
    if "thin" in names:
        seps = [1.2] if args.quick else [1.8, 1.5, 1.2, 0.9, 0.6]
        rows, counts, *_ = pair(thin_instrument(), 662.0, 0.3, 31, seps, flux2, METHODS,
                                lambda s: f"thin {s:.1f} deg")
        every += rows
        chunks.append("\n".join(counts) + table(rows, "thin mask pair (0.5 cm Pb, 662 keV)")
                      + "\n\n" + dip_vs_separation(rows, "thin", 0.3))
        print(chunks[-1], flush=True)
    if "proto" in names:
        from rotmod.io import load_instrument

        pix = 5.0 / 60
        seps = [35 / 60, 30 / 60] if args.quick else [v / 60 for v in (35, 30, 25, 20, 15, 10)]
        rows, counts, *_ = pair(load_instrument("prototype"), 122.0, pix, 31, seps,
                                PROTO_FLUX, METHODS, lambda s: f"proto {s * 60:.0f}'")
        every += rows
        chunks.append("\n".join(counts) + table(rows, "lab prototype pairs (122 keV)")
                      + "\n\n" + dip_vs_separation(rows, "proto", pix))
        print(chunks[-1], flush=True)
    if "field" in names:
        inst = field_instrument()
        grid = SkyGrid.paper()
        t0 = time.perf_counter()
        resp = build_response(inst, grid, TimeBinning(N_BINS, "average"), energy=662.0)
        log.info("response %s in %.1f s", resp, time.perf_counter() - t0)
        xy = [(-4.1, 3.1), (1.9, -0.9), (5.1, 5.1)]
        flux = [10.0, 5.0, 3.0]
        y, bkg, src = simulate(inst, grid, xy, flux, 662.0, seed=30)
        rows: list = []
        run_methods(resp, y, bkg, grid, src, flux, 1.0, METHODS, "field", rows)
        every += rows
        chunks.append(f"field: {y.sum():.3g} counts (background {bkg:.2f} /s per detector)"
                      + table(rows, "paper's 14 deg field, 70 x 70, 3 sources"))
        print(chunks[-1], flush=True)
    if args.seeds > 0:
        chunks.append(seeds_table(args.seeds))
        print(chunks[-1], flush=True)
    chunks.append(versus_mlem(every))
    print(chunks[-1], flush=True)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(f"load average {os.getloadavg()}\n" + "\n\n".join(chunks) + "\n")


if __name__ == "__main__":
    main()
