"""How dense the true-energy nodes of a source's energy-resolved response must be (issue 23).

Injects the expected counts of an E^-2 source (K = 2e-4 photons cm^-2 s^-1 keV^-1 at 100
keV; 7 detectors of 5 cm x 5 cm NaI under 3/3/3 cm slats 1 m up; 8 deg off axis; 4e7 counts,
rounded, so that the statistical error is small) computed with 512 nodes from 60 keV to 3 MeV,
and fits it with responses of 64, 128, 256 and 512 nodes (each grid's detector response its
own Monte Carlo draw).  Prints the fitted K and index per grid.  Results: docs/spectra.md.

    NUMBA_NUM_THREADS=1 python benchmarks/spectra_nodes.py
"""

from __future__ import annotations

import time

import numpy as np

from rotmod import Instrument
from rotmod.energy import EnergyResolution
from rotmod.geometry import DetectorArray, Mask
from rotmod.materials import Material
from rotmod.response import build_response
from rotmod.sky import SkyGrid
from rotmod.sources.spectra import expected_counts, fit_spectra, spectral_columns
from rotmod.spectral import PowerLaw
from rotmod.spectral.detector import tabulate_response


def main() -> None:
    hexa = DetectorArray.hexagonal(5.0, rings=1)
    det = DetectorArray(hexa.positions, 5.0, thickness=5.0,
                        material=Material("NaI", density=3.67))
    inst = Instrument(Mask(3.0, 3.0, 3.0, 100.0), det, rotation_period=60.0)
    resp = build_response(inst, SkyGrid.square(4, 1.0), 30, energy=300.0)
    channels = np.geomspace(50.0, 2500.0, 33)
    cols, t0 = {}, time.time()
    for n in (64, 128, 256, 512):
        nodes = np.geomspace(60.0, 3000.0, n)
        dr = tabulate_response(det, nodes, [0.0, 10.0], channels,
                               resolution=EnergyResolution.nai(), n_photons=20000, seed=n)
        cols[n] = spectral_columns(resp, (8.0, 40.0), dr)
        print(f"{n} nodes tabulated, {time.time() - t0:.0f} s", flush=True)
    truth, start = PowerLaw(2e-4, -2.0), PowerLaw(4e-4, -1.6)
    expo = np.full(30, 1e5)
    y = np.round(expected_counts(cols[512], expo, [truth], background=0.05)).astype(int)
    print(f"\n{y.sum():.3g} counts; truth K = {truth.K:g}, index = {truth.index:g}")
    print(f"{'nodes':>6} {'K':>12} {'index':>9} {'index error':>12}")
    for n, c in cols.items():
        f = fit_spectra(c, y, expo, [start])
        print(f"{n:>6} {f.models[0].K:>12.5e} {f.models[0].index:>9.4f} "
              f"{f.errors[0]['index']:>12.4f}")


if __name__ == "__main__":
    main()
