"""The instrument as built: the exact model against the Monte Carlo, one effect at a time.

    python scripts/validate_asbuilt.py [--n-photons 200000] [--n-angles 48]

Prints a markdown table (recorded in docs/validation.md): for each scenario, the effective
degrees of freedom, Pearson's chi2/dof with the model's binomial variance (as
``rotmod.paper.validation.chi_square``), what a 0.5 % error of the unobstructed flux would
add to it, and the largest |model - MC|.  Each scenario has an on-axis and an off-axis
detector (one far outside the mask for the finite mask) and two sources (azimuths 32 and
127 deg) at ``n_angles`` mask angles over a turn (fixed angles: a bin average by the
midpoint rule on 8 sub-angles would itself be off by up to 2e-3 at 7.5 deg bins).
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np
from scipy import stats

from rotmod import DetectorArray, Instrument, Mask, Material, get_model
from rotmod.montecarlo import simulate_profiles
from rotmod.paper.validation import chi_square

PB = Material("Pb", density=11.34)  # XCOM attenuation at each energy
NAI = Material("NaI", density=3.67)
POS = np.array([[0.0, 0.0], [8.4, 4.85]])


def base(h: float = 2.0, a: float = 3.8, L: float = 114.55) -> Mask:
    return Mask(a, a, h, L, PB)


def flat(mask: Mask, c: float = 3.8) -> Instrument:
    return Instrument(mask, DetectorArray(POS, c))


def thick(mask: Mask, c: float = 3.8) -> Instrument:
    return Instrument(mask, DetectorArray(POS, c, 2.5, NAI))


#: (name, what it shows, instrument, theta (deg), energy (keV), distance (cm) or None).
SCENARIOS = [
    ("offset+tilt", "1.5 cm axis offset, 3 deg tilt (h = 6 cm)",
     flat(dataclasses.replace(base(6.0), axis_offset_x=0.7, axis_offset_y=-1.3, tilt_x=3.0,
                              tilt_y=-2.0)), 6.0, 662.0, None),
    ("prototype misalignment", "1 mm offset, 0.2 deg tilt",
     flat(dataclasses.replace(base(), axis_offset_x=0.1, tilt_y=0.2)), 3.0, 662.0, None),
    ("slat pattern", "slats of 1 and 3 cm in a 7.6 cm period, 5 deg tilt (h = 6 cm)",
     flat(dataclasses.replace(base(6.0), slat_edges=(0.5, 1.5, 3.0, 5.8), tilt_x=5.0)),
     6.0, 662.0, None),
    ("finite mask", "disc of 12 cm radius: one detector inside, one outside",
     Instrument(dataclasses.replace(base(), outline="circle", outline_size=12.0),
                DetectorArray([[0.0, 0.0], [25.0, 0.0]], 3.8)), 2.0, 662.0, None),
    ("distance 2 m", "source 200 cm from the array", flat(base()), 3.0, 662.0, 200.0),
    ("distance 5 m", "source 500 cm from the array", flat(base()), 3.0, 662.0, 500.0),
    ("distance 10 m", "source 1000 cm from the array", flat(base()), 3.0, 662.0, 1000.0),
    ("thick 662 keV", "2.5 cm NaI, parallel rays (mu H = 0.7)", thick(base()), 10.0, 662.0,
     None),
    ("thick 122 keV", "2.5 cm NaI, parallel rays (mu H = 9)", thick(base()), 10.0, 122.0,
     None),
    ("thick 2 m, tilt", "2.5 cm NaI, 200 cm, 1 mm offset, 0.2 deg tilt",
     thick(dataclasses.replace(base(), axis_offset_x=0.1, tilt_y=0.2)), 3.0, 662.0, 200.0),
    ("prototype-lab at 2 m", "the lab prototype as built, 122 keV",
     thick(dataclasses.replace(base(), axis_offset_x=0.1, tilt_y=0.2)), 3.0, 122.0, 200.0),
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n-photons", type=int, default=200_000)
    ap.add_argument("--n-angles", type=int, default=48)
    args = ap.parse_args()
    n_ang = args.n_angles
    xi = (np.arange(n_ang) + 0.5) * (360.0 / n_ang)
    phi = np.array([32.0, 127.0])
    print(f"Monte Carlo photons per (detector, angle, source) cell: {args.n_photons}; "
          f"{n_ang} mask angles; 2 detectors x 2 azimuths.\n")
    print("| scenario | what | dof | chi2/dof | p | 0.5 % adds | max \\|model - MC\\| | "
          "MC (s) | model (s) |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for i, (name, what, inst, theta, energy, D) in enumerate(SCENARIOS):
        th = np.full(2, theta)
        t0 = time.perf_counter()
        mc = simulate_profiles(inst, th, phi, xi, energy=energy, n_photons=args.n_photons,
                               distance=D, seed=1000 + i)
        t1 = time.perf_counter()
        P = get_model("exact").profile(inst, th, phi, xi, energy, distance=D)
        t2 = time.perf_counter()
        p = P / np.asarray(mc.scale)
        chi2, dof = chi_square(p, mc.counts, mc.n_photons)
        shifted = np.clip(p + 0.005 * np.sign(0.5 - p + 1e-300), 0, 1)
        lam, _ = chi_square(shifted, np.round(p * mc.n_photons), mc.n_photons)
        print(f"| {name} | {what} | {dof:.0f} | {chi2 / dof:.3f} | "
              f"{stats.chi2.sf(chi2, dof):.2f} | {lam / dof:.3g} | "
              f"{np.abs(mc.fraction - P).max():.2e} | {t1 - t0:.1f} | {t2 - t1:.2f} |",
              flush=True)


if __name__ == "__main__":
    main()
