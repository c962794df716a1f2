"""Why the light curve is in the model (issue 22): the position's bias with and without it.

One bright burst that changes within a turn -- a Norris pulse (rise 0.1 s, decay 1.5 s by
default, so most of its counts arrive in half of a 4 s turn) 30 deg off axis on the survey
instrument of ``bursts_calibration.py`` -- is injected ``--n`` times with different noise.
Each time, the background and light curve are measured as ``analyse_burst`` measures them,
and the likelihood's maximum is climbed from the true position (the search is not under test here)
twice on the same counts:

* **with L(t)**: the response weighted by the Norris pulses fitted as seen from the climb's
  start (the truth), as :func:`rotmod.bursts.localise_burst` does from each of its starts;
* **constant**: a source constant over the burst's extent (the light curve ignored).

The mean offset from the truth (radial and azimuthal, in the instrument frame) over the
injections is the bias; its standard error comes from their scatter.  The mean of the two
fits' difference on the same counts isolates the light curve's effect from the noise they
share.  Both are in units of
r90 = 2.146 sigma (a 2-D Gaussian's 90 % radius, sigma the scatter per axis of the fits
with L(t)).  Printed and written to ``benchmarks/results/bursts_lightcurve_bias.txt``.

    NUMBA_NUM_THREADS=1 python benchmarks/bursts_lightcurve_bias.py --n 40
    NUMBA_NUM_THREADS=1 python benchmarks/bursts_lightcurve_bias.py --n 300 --decay 0.5 \
        --peak 60 --jobs 2
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import astropy.units as u
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bursts_calibration as cal

OUT = cal.ROOT / "benchmarks" / "results" / "bursts_lightcurve_bias.txt"
THETA, PHI = 30.0, 70.0
PULSE = (100.0, 0.1, 1.5, 30.0)   # start (s), rise (s), decay (s), peak (photons/s/face)


def fits(seed: int, pulse: tuple[float, ...]) -> dict:
    from rotmod.bursts.analysis import _boxcar, _measurements
    from rotmod.bursts.inject import simulate_burst
    from rotmod.bursts.localisation import (
        _background_rates,
        bin_events,
        burst_pulses,
        burst_response,
        default_time_bins,
    )
    from rotmod.bursts.search import search
    from rotmod.sky.points import PositionList
    from rotmod.sources.fitting import SourceFitter, geometric_scale
    from rotmod.sources.model import PointSource, SkyModel

    inst, att = cal.setup()
    truth = att.to_sky(THETA * u.deg, PHI * u.deg)
    lc = cal.light_curve([list(pulse)])
    ev = simulate_burst(inst, truth, lc, t_start=cal.T_START, t_stop=cal.T_STOP,
                        background=cal.BACKGROUND, energy=cal.ENERGY, attitude=att, seed=seed)
    cand = max(search(ev).candidates, key=lambda c: c.significance)
    bkg, blocks, window, _, _ = _measurements(ev, *cand.interval, 1)
    counts = bin_events(ev, *window, time_bins=default_time_bins(inst, THETA + 5.0))
    unit = burst_response(counts, lambda a: PositionList.from_coords(a.pointing, a),
                          energy=cal.ENERGY)
    data = counts.data(_background_rates(bkg, counts))
    src = dataclasses.replace(PointSource(truth), free_position=True)
    out = {}
    base = burst_pulses(blocks, counts, bkg)
    seen = burst_pulses(blocks, counts, bkg, unit, PointSource(truth), base)
    for name, w in (("lc", seen.shape(counts.edges)),
                    ("const", _boxcar(*blocks.interval)(counts.edges))):
        f = SourceFitter(unit.with_weight(w), data)
        m = f.fit_positions(f.maximise(SkyModel((src,)))[0],
                            scale=0.125 * geometric_scale(inst), precision=1e-3)
        th, ph = att.to_instrument(m.sources[0].position)
        out[name] = (float(th.to_value(u.deg)), float(ph.to_value(u.deg)))
        if name == "lc":
            out["ts"] = 2.0 * (f.maximise(m)[1].loglike - f.maximise(SkyModel(()))[1].loglike)
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=40)
    p.add_argument("--decay", type=float, default=PULSE[2], help="decay time (s)")
    p.add_argument("--peak", type=float, default=PULSE[3], help="peak (photons/s/face)")
    p.add_argument("--jobs", type=int, default=1,
                   help="worker processes (set NUMBA_NUM_THREADS=1 with more than one)")
    p.add_argument("--out", type=Path, default=OUT, help="appended to")
    args = p.parse_args()
    pulse = (PULSE[0], PULSE[1], args.decay, args.peak)
    recs, load, t0 = [], [], time.perf_counter()
    with ProcessPoolExecutor(args.jobs) as pool:
        for s, rec in enumerate(pool.map(fits, range(1000, 1000 + args.n),
                                         [pulse] * args.n)):
            load.append(os.getloadavg()[0])
            recs.append(rec)
            print(f"{s + 1}/{args.n} ({time.perf_counter() - t0:.0f} s)", rec, flush=True)
    off = {}
    for name in ("lc", "const"):
        th = np.array([r[name][0] for r in recs])
        ph = np.array([r[name][1] for r in recs])
        dphi = (ph - PHI + 180.0) % 360.0 - 180.0
        off[name] = np.stack([th - THETA, np.sin(np.radians(THETA)) * dphi], axis=1)
    sigma = float(np.sqrt(0.5 * np.sum(np.var(off["lc"], axis=0, ddof=1))))
    r90 = 2.146 * sigma
    lines = [
        "Light curve in the model or not (issue 22): bias of the position over injections",
        f"  burst: Norris pulse rise {pulse[1]} s, decay {pulse[2]} s, peak {pulse[3]} "
        f"photons/s/face at theta {THETA:g}, phi {PHI:g} deg; 4 s turn; {args.n} injections "
        f"({args.jobs} processes); "
        f"median sqrt TS {np.median(np.sqrt([r['ts'] for r in recs])):.1f}",
        f"  scatter per axis (with L(t)) {sigma:.4f} deg -> r90 {r90:.4f} deg; load average "
        f"(1 min) median {np.median(load):.2f} on {os.cpu_count()} cores",
        "",
        "| model | radial bias (r90) | azimuthal bias (r90) | |bias| (r90) | rms offset (r90) |",
        "|---|---|---|---|---|",
    ]
    # The difference on the same counts: the noise common to both fits cancels, so this is
    # the light curve's own effect, measured far more precisely than either bias.
    off["diff"] = off["const"] - off["lc"]
    for name, label in (("lc", "with L(t)"), ("const", "constant (L ignored)"),
                        ("diff", "constant - with L(t), same counts")):
        o = off[name] / r90
        mean = o.mean(axis=0)
        se = o.std(axis=0, ddof=1) / np.sqrt(len(o))
        lines.append(f"| {label} | {mean[0]:+.3f} +- {se[0]:.3f} | {mean[1]:+.3f} +- "
                     f"{se[1]:.3f} | {np.hypot(*mean):.3f} | "
                     f"{np.sqrt(np.mean(np.sum(o ** 2, axis=1))):.3f} |")
    text = "\n".join(lines)
    print(text)
    with args.out.open("a") as f:
        f.write(text + "\n\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
