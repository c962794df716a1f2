"""Typical background rates of rotmod.spectral.background: the table of docs/background.md.

Run: ``PYTHONPATH=src python benchmarks/background.py`` (a few seconds).  A bare 5 cm x 5 cm
NaI(Tl) at Fort Sumner (NRLMSIS, default date), its response at 2000 photons per node (30 keV -
3 MeV, 511 keV added as a node), 16 channels: counts/s per component at 30-40 km, the albedo
alone, the spectrum per channel at 33 km, and the cost of a flight's rates.
"""

from __future__ import annotations

import time

import numpy as np

from rotmod import DetectorArray, Material
from rotmod.energy import EnergyResolution
from rotmod.spectral.atmosphere import Atmosphere
from rotmod.spectral.background import BalloonBackground
from rotmod.spectral.detector import tabulate_response


def main() -> None:
    det = DetectorArray([[0.0, 0.0]], 5.0, 5.0, Material("NaI", density=3.67))
    nodes = np.unique(np.r_[np.geomspace(30.0, 3000.0, 25), 511.0])
    ch = np.geomspace(30.0, 3000.0, 17)
    t0 = time.perf_counter()
    resp = tabulate_response(det, nodes, [0, 20, 40, 60, 75, 85, 89], ch,
                             resolution=EnergyResolution.nai(), n_photons=2000, seed=1)
    print(f"response: {time.perf_counter() - t0:.1f} s")
    atm = Atmosphere.from_msis()
    bg = BalloonBackground(atm)
    print("altitude  X(g/cm2)   cxb  continuum  line   (counts/s, 30-3000 keV)")
    for h in (30.0, 33.0, 36.0, 40.0):
        c = bg.components(resp, det, h)
        print(f"{h:6.1f} {float(bg.depth(h)):9.2f} {c['cxb'].sum():7.1f} "
              f"{c['continuum'].sum():9.1f} {c['line'].sum():6.1f}")
    up = BalloonBackground(atm, mask_opacity=1.0).components(resp, det, 33.0)
    print(f"upward only: continuum {up['continuum'].sum():.1f}, line {up['line'].sum():.2f}")
    c = bg.components(resp, det, 33.0)
    print("channel (keV)      cxb   continuum   line   (counts/s at 33 km)")
    for i in range(ch.size - 1):
        print(f"{ch[i]:7.1f}-{ch[i + 1]:7.1f} {c['cxb'][i]:8.4f} {c['continuum'][i]:9.4f} "
              f"{c['line'][i]:7.4f}")
    t0 = time.perf_counter()
    rates = bg.flight_rates(resp, det, np.linspace(30.0, 36.0, 36001), step=0.1)
    print(f"flight rates, 36001 times over 30-36 km: {time.perf_counter() - t0:.2f} s, "
          f"shape {rates.shape}")


if __name__ == "__main__":
    main()
