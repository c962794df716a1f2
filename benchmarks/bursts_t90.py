"""T90 and its error against the truth (issue 22), on many injected bursts.

The bursts of ``bursts_calibration.py`` (same instrument, background, seeds and truths: burst
``i`` here is burst ``i`` there) are simulated, searched and measured -- background, Bayesian
blocks, durations (:func:`rotmod.bursts.analysis._measurements`, the first three steps of
``analyse_burst``) -- without the localisation, so that hundreds are cheap.  Each burst's
T90 error is computed both ways in the same run:

* **model redraws** (ours): the errors' Poisson redraws drawn from the background plus the
  burst's blocks;
* **observed redraws** (the straightforward bootstrap): redraws of the observed counts, on
  the same window.

Printed (and written to ``benchmarks/results/bursts_t90.txt``): the fraction of bursts with
``|T90 - true| < 1 and 2 sigma`` for each, overall and by trigger significance, and the
median of ``(T90 - true) / sigma``.

    python benchmarks/bursts_t90.py --n 300
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bursts_calibration as cal

OUT = cal.ROOT / "benchmarks" / "results" / "bursts_t90.txt"


def one(i: int, seed: int, inst, att) -> dict:
    from rotmod.bursts.analysis import _measurements
    from rotmod.bursts.inject import simulate_burst
    from rotmod.bursts.measure import durations, true_durations
    from rotmod.bursts.search import search

    tr = cal.draw_truth(seed, i)
    lc = cal.light_curve(tr["pulses"])
    true = true_durations(lc, *cal.TRUTH_WINDOW)
    ev = simulate_burst(inst, att.to_sky(tr["theta"], tr["phi"]), lc, t_start=cal.T_START,
                        t_stop=cal.T_STOP, background=cal.BACKGROUND, energy=cal.ENERGY,
                        attitude=att, seed=tr["sim_seed"])
    over = [c for c in search(ev).candidates
            if c.interval[1] > cal.T_BURST - 1.0
            and c.interval[0] < true.t90_start + true.t90 + 1.0]
    rec = {"index": i, "true_t90": true.t90, "n_pulses": len(tr["pulses"])}
    if not over:
        return rec | {"detected": False}
    cand = max(over, key=lambda c: c.significance)
    try:
        bkg, _, _, dur, window = _measurements(ev, *cand.interval, 1)
    except Exception as exc:  # recorded, not fatal
        return rec | {"detected": True, "error": f"{type(exc).__name__}: {exc}"}
    observed = durations(ev, window, bkg)
    return rec | {"detected": True, "significance": cand.significance, "t90": dur.t90,
                  "err_model": dur.t90_err, "err_observed": observed.t90_err}


def report(recs: list[dict], load: list[float]) -> str:
    ok = [r for r in recs if "t90" in r and np.isfinite(r["t90"])]
    lines = [f"T90 against the truth (issue 22): {len(recs)} bursts injected, "
             f"{sum(r.get('detected', False) for r in recs)} detected, {len(ok)} with a T90",
             f"  load average (1 min) median {np.median(load):.2f} on {os.cpu_count()} cores",
             "",
             "| errors from | bursts | within 1 sigma | within 2 sigma | median z |",
             "|---|---|---|---|---|"]
    bins = [("all", 0, np.inf), ("trigger < 10 sigma", 0, 10), ("10-30 sigma", 10, 30),
            (">= 30 sigma", 30, np.inf)]
    for key, name in (("err_model", "model redraws (ours)"),
                      ("err_observed", "observed redraws")):
        for label, lo, hi in bins:
            sel = [r for r in ok if lo <= r["significance"] < hi]
            if not sel:
                continue
            z = np.array([(r["t90"] - r["true_t90"]) / r[key] for r in sel])
            k1, k2, n = int(np.sum(np.abs(z) < 1)), int(np.sum(np.abs(z) < 2)), len(sel)
            a, b = cal.binom_2sigma(k2, n)
            lines.append(f"| {name}, {label} | {n} | {k1 / n:.3f} | {k2 / n:.3f} "
                         f"(2 sigma {a:.2f}-{b:.2f}) | {np.median(z):+.2f} |")
    lines.append("")
    lines.append("Gaussian: 0.683 within 1 sigma, 0.954 within 2 sigma.")
    return "\n".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=300)
    p.add_argument("--seed", type=int, default=cal.SEED)
    p.add_argument("--out", type=Path, default=OUT)
    args = p.parse_args()
    inst, att = cal.setup()
    recs, load = [], []
    t0 = time.perf_counter()
    for i in range(args.n):
        load.append(os.getloadavg()[0])
        recs.append(one(i, args.seed, inst, att))
        if (i + 1) % 10 == 0:
            print(f"{i + 1}/{args.n} bursts, {time.perf_counter() - t0:.0f} s", flush=True)
    text = report(recs, load)
    print(text)
    args.out.write_text(text + "\n")
    args.out.with_suffix(".json").write_text(json.dumps(recs, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
