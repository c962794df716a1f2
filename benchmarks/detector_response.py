"""Detector response benchmarks (rotmod.spectral.detector): the 3" x 3" NaI(Tl) validation
table, the interpolation error in zenith angle, and the time to tabulate a response.

Run ``NUMBA_NUM_THREADS=1 PYTHONPATH=src python benchmarks/detector_response.py [--quick]``;
prints markdown tables (recorded in docs/detector_response.md with the machine load).
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import time

import numba
import numpy as np
from scipy.integrate import quad

from rotmod import DetectorArray, Material
from rotmod.energy import EnergyResolution
from rotmod.spectral.detector import simulate_deposits, tabulate_response

NAI = Material("NaI", density=3.67)


def total_efficiency_closed_form(mu: float, R: float, H: float, d: float) -> float:
    """Interactions per photon crossing the top face for an on-axis point source at ``d``:
    the cone average of ``1 - exp(-mu l(alpha))`` (Vegors, Marsden & Heath 1958 geometry),
    ``l = H / cos`` through the bottom, ``(R - d tan) / sin`` through the side."""
    a_max = math.atan(R / d)
    a_side = math.atan(R / (d + H))  # steeper rays leave through the bottom

    def f(a):
        if a <= a_side:
            length = H / math.cos(a)
        else:
            length = (R - d * math.tan(a)) / math.sin(a)
        return -math.expm1(-mu * length) * math.sin(a)

    num = quad(f, 0.0, a_side, epsabs=0, epsrel=1e-12)[0]
    num += quad(f, a_side, a_max, epsabs=0, epsrel=1e-12)[0]
    return num / (1.0 - math.cos(a_max))


def validation(n: int) -> None:
    det = DetectorArray([[0.0, 0.0]], 7.62, 7.62, NAI)
    print(f"\n### 3\" x 3\" NaI(Tl), bare crystal, point source on the axis ({n:.0e} photons "
          "each)\n")
    print("| d (cm) | E (keV) | interactions / photon on face (MC) | closed form | "
          "abs. total eff. (>= 30 keV) | abs. peak eff. (1e-3) | photofraction | "
          "P/T (>= 30 keV) | P/T with K-escape (peak window 40 keV) | "
          "P/T, Rayleigh undeflected |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for d in (10.0, 25.0):
        for e in (122.0, 662.0, 1332.0):
            s = simulate_deposits(det, e, distance=d, n_photons=n, seed=int(e) + int(d))
            f = simulate_deposits(det, e, distance=d, n_photons=n, seed=int(e) + int(d) + 1,
                                  rayleigh="forward")
            mu = float(NAI.linear_attenuation(e))
            cf = total_efficiency_closed_form(mu, 3.81, 7.62, d)
            g = s.solid_angle
            tot = g * s.interaction * s.above(30.0)
            pk = 1e3 * g * s.interaction * s.full_energy
            pk_err = 1e3 * g * s.interaction * s.error("full_energy")
            print(f"| {d:g} | {e:g} | {s.interaction:.5f} ± {s.interaction_error:.5f} | "
                  f"{cf:.5f} | {tot:.5f} | {pk:.4f} ± {pk_err:.4f}"
                  f" | {s.full_energy:.4f} ± {s.error('full_energy'):.4f} | "
                  f"{s.peak_to_total(30.0):.4f} ± {s.error('peak_to_total', 30.0):.4f} | "
                  f"{s.peak_to_total(30.0, 40.0):.4f} ± "
                  f"{s.error('peak_to_total', 30.0, 40.0):.4f} | "
                  f"{f.peak_to_total(30.0):.4f} ± {f.error('peak_to_total', 30.0):.4f} |")


def theta_interpolation(n: int) -> None:
    det = DetectorArray([[0.0, 0.0]], 5.0, 5.0, NAI)
    nodes = np.arange(0.0, 81.0, 10.0)
    mids = nodes[:-1] + 5.0
    energies = np.array([100.0, 662.0, 2000.0])
    ch = np.linspace(0.0, 2200.0, 257)
    res = EnergyResolution.nai()
    grid = tabulate_response(det, energies, nodes, ch, resolution=res, n_photons=n, seed=1)
    direct = tabulate_response(det, energies, mids, ch, resolution=res, n_photons=n, seed=2)
    again = tabulate_response(det, energies, mids, ch, resolution=res, n_photons=n, seed=3)
    interp = grid.matrix_at(mids)
    d_interp = np.abs(interp - direct.matrix).sum(axis=2)  # L1 distance of the rows
    d_noise = np.abs(again.matrix - direct.matrix).sum(axis=2)
    e_interp = np.abs(grid.interaction_at(mids) / direct.interaction - 1)
    print(f"\n### Interpolation in theta (5 cm x 5 cm NaI, nodes every 10 deg, {n:.0e} photons)"
          "\n")
    print("| E (keV) | max L1(interp - direct) | max L1(MC - MC) | max rel. err. E0 | "
          "its MC error |")
    print("|---|---|---|---|---|")
    for i, e in enumerate(energies):
        rel = np.max(direct.interaction_error[:, i] / direct.interaction[:, i])
        print(f"| {e:g} | {d_interp[:, i].max():.4f} | {d_noise[:, i].max():.4f} | "
              f"{e_interp[:, i].max():.2e} | {rel:.1e} |")


def timing(photons: list[int]) -> None:
    det = DetectorArray([[0.0, 0.0]], 5.0, 5.0, NAI)
    energies = np.geomspace(20.0, 10_000.0, 60)
    angles = np.linspace(0.0, 85.0, 10)
    ch = np.geomspace(10.0, 12_000.0, 257)
    res = EnergyResolution.nai()
    tabulate_response(det, energies[:2], angles[:1], ch, resolution=res, n_photons=100)  # warm
    print("\n### Tabulating 10 angles x 60 energies (20 keV - 10 MeV) x 256 channels, 5 cm x 5 cm"
          " NaI\n")
    print("| photons per (angle, energy) | time (s) | photons / s |")
    print("|---|---|---|")
    for n in photons:
        t = time.perf_counter()
        tabulate_response(det, energies, angles, ch, resolution=res, n_photons=n, seed=4)
        dt = time.perf_counter() - t
        print(f"| {n:.0e} | {dt:.1f} | {600 * n / dt:.2e} |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer photons (a smoke run)")
    args = ap.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"numba threads {numba.get_num_threads()}, load average {os.getloadavg()}")
    validation(200_000 if args.quick else 4_000_000)
    theta_interpolation(20_000 if args.quick else 400_000)
    timing([1000, 5000] if args.quick else [1000, 10_000, 50_000])
    print(f"\nload average at the end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
