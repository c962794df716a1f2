"""Burst detection efficiency against fluence (issue 22), at the default false-alarm rate.

The survey instrument (37 detectors of 5 cm under 3/3/3 cm lead 1 m up, a 4 s turn), 1.5
counts/s/detector of background, 300 keV, a fixed attitude.  For each fluence, ``--n``
single Norris pulses (rise log-uniform 0.1-1 s, decay log-uniform 0.3-15 s; theta uniform in
cos(theta) over 0-60 deg, phi uniform) are injected in 300 s of data (exact model,
:func:`rotmod.bursts.simulate_burst`) and searched (:func:`rotmod.bursts.search`, one false
alarm per day); a burst is detected when a candidate overlaps it.  The fluence is photons per
cm^2 of projected detector face (so that the same fluence gives the same counts at every
off-axis angle before the mask).

    python benchmarks/bursts_detection.py     # writes benchmarks/results/bursts_detection.txt
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import astropy.units as u
import numpy as np
from scipy.stats import beta

from rotmod.bursts import norris_pulse, search, simulate_burst
from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.sky import Attitude

ROOT = Path(__file__).resolve().parent.parent
FLUENCES = (0.05, 0.1, 0.2, 0.3, 0.5, 0.8, 1.2, 2.0)   # photons/cm^2


def pulse_integral(rise: float, decay: float) -> float:
    """Integral of a unit-peak Norris pulse (s), numerically."""
    t = np.linspace(0.0, 40.0 * decay + 40.0 * rise, 400001)
    return float(np.trapezoid(norris_pulse(t, 0.0, rise, decay, 1.0), t))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=40, help="bursts per fluence")
    p.add_argument("--seed", type=int, default=20261126)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" /
                   "bursts_detection.txt")
    args = p.parse_args()
    inst = Instrument(Mask(3, 3, 3, 100), DetectorArray.hexagonal(5, rings=3),
                      rotation_period=4.0)
    att = Attitude(30.0, 40.0, 10.0)
    face = np.pi * 2.5**2
    lines = []

    def say(text: str) -> None:
        print(text, flush=True)
        lines.append(text)

    t0 = time.perf_counter()
    say("Burst detection efficiency (issue 22): search at 1 false alarm/day, 300 s of data")
    say(f"  survey instrument, 1.5 counts/s/detector, 300 keV; {args.n} bursts per fluence; "
        f"seed {args.seed}")
    say("")
    say("| fluence (ph/cm2) | detected | fraction | 68 % interval | median net counts |")
    say("|---|---|---|---|---|")
    for j, fluence in enumerate(FLUENCES):
        rng = np.random.default_rng([args.seed, j])
        found, counts = 0, []
        for _ in range(args.n):
            theta = np.degrees(np.arccos(rng.uniform(np.cos(np.radians(60.0)), 1.0)))
            phi = rng.uniform(0.0, 360.0)
            rise = float(np.exp(rng.uniform(np.log(0.1), np.log(1.0))))
            decay = float(np.exp(rng.uniform(np.log(0.3), np.log(15.0))))
            # Peak (photons/s per face) so that the fluence per projected cm^2 is `fluence`.
            area = face * np.cos(np.radians(theta))
            amp = fluence * area / pulse_integral(rise, decay)
            ev = simulate_burst(inst, att.to_sky(theta * u.deg, phi * u.deg),
                                lambda t, r=rise, d=decay, a=amp: norris_pulse(t, 100.0, r, d, a),
                                t_start=0.0, t_stop=300.0, background=1.5, energy=300.0,
                                attitude=att, seed=rng)
            counts.append(int(np.sum(ev.source == 0)))
            hit = [c for c in search(ev).candidates
                   if c.interval[1] > 100.0 and c.interval[0] < 100.0 + 5 * decay + 5 * rise]
            found += bool(hit)
        lo, hi = (beta.ppf(0.16, found, args.n - found + 1) if found else 0.0,
                  beta.ppf(0.84, found + 1, args.n - found) if found < args.n else 1.0)
        say(f"| {fluence:g} | {found}/{args.n} | {found / args.n:.2f} | [{lo:.2f}, {hi:.2f}] | "
            f"{np.median(counts):.0f} |")
    say("")
    say(f"  {time.perf_counter() - t0:.0f} s; load average {os.getloadavg()[0]:.2f}")
    args.out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
