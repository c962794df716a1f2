"""Calibration of forward-folded spectral fits on the modulator's counts (issue 23).

Injects Poisson realisations of a source's counts per detector, mask-angle bin and channel
(the energy-resolved response: exact-model columns at each true energy x the detector Monte
Carlo's redistribution) on a background unknown to the fit, fits every realisation with
:func:`rotmod.sources.spectra.fit_spectra` (one background level per detector and channel
fitted), and reports for every parameter the fraction of realisations whose 1-sigma and
1.645-sigma intervals hold the truth, the mean pull (bias in units of the error) and the pull
width.  Instrument: 37 detectors of 5 cm x 5 cm NaI(Tl) under 3/3/3 cm lead slats 1 m up
(the survey instrument of issue 21 with thick detectors), source 8 deg off axis.

    NUMBA_NUM_THREADS=1 python benchmarks/spectra_calibration.py --n 200 --out results.json
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from rotmod import Instrument
from rotmod.energy import EnergyResolution
from rotmod.geometry import DetectorArray, Mask
from rotmod.materials import Material
from rotmod.response import build_response
from rotmod.sky import SkyGrid
from rotmod.sources.spectra import (
    SpectralColumns,
    expected_counts,
    fit_spectra,
    spectral_columns,
)
from rotmod.spectral import Band, PowerLaw
from rotmod.spectral.detector import tabulate_response


def wilson(k: int, n: int, z: float = 2.0) -> tuple[float, float]:
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return c - h, c + h


def survey(photons: int, positions: tuple, n_bins: int = 60
           ) -> tuple[SpectralColumns, np.ndarray]:
    """The survey instrument's energy-resolved columns for sources at ``positions`` (64
    nodes, 32 channels) and the background rate per channel (counts/s per detector)."""
    hexa = DetectorArray.hexagonal(5.0, rings=3)
    det = DetectorArray(hexa.positions, 5.0, thickness=5.0,
                        material=Material("NaI", density=3.67))
    inst = Instrument(Mask(3.0, 3.0, 3.0, 100.0), det, rotation_period=60.0)
    resp = build_response(inst, SkyGrid.square(4, 1.0), n_bins, energy=300.0)
    nodes = np.geomspace(60.0, 3000.0, 64)
    channels = np.geomspace(50.0, 2500.0, 33)
    dr = tabulate_response(det, nodes, [0.0, 5.0, 10.0], channels,
                           resolution=EnergyResolution.nai(), n_photons=photons, seed=1)
    cols = spectral_columns(resp, positions, dr)
    # Background per detector and channel: a falling continuum, ~2 counts/s per detector in
    # all (the fit does not know it).
    ch_c = np.sqrt(channels[1:] * channels[:-1])
    bkg_shape = (ch_c / 100.0) ** -1.3 * np.diff(channels)
    return cols, 2.0 * bkg_shape / bkg_shape.sum()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="realisations of the steady source")
    ap.add_argument("--n-burst", type=int, default=120, help="realisations of each burst case")
    ap.add_argument("--photons", type=int, default=20000, help="detector MC photons per node")
    ap.add_argument("--out", default=None, help="JSON file for the pulls")
    args = ap.parse_args()
    t0 = time.time()
    n_bins = 60
    cols, bkg = survey(args.photons, (8.0, 40.0), n_bins)
    nodes = cols.energies
    t_setup = time.time() - t0
    burst = (Band(0.03, -1.0, 300.0, -2.5), Band(0.02, -1.2, 400.0, -2.2),
             np.full(n_bins, 1.0))
    # name: (truth, start, exposure per bin, seconds of background measured off the burst,
    #        realisations)
    cases = {
        # A steady source: 60 bins x 1000 s (one 16.7 h observation); background fitted.
        "power law (K=2e-4 at 100 keV, index -2), 16.7 h": (
            PowerLaw(2e-4, -2.0), PowerLaw(4e-4, -1.6), np.full(n_bins, 1000.0), None,
            args.n),
        # A bright burst over one 60 s turn, the background measured over 600 s around it.
        "Band burst (K=0.03, alpha=-1, xp=300 keV, beta=-2.5), 60 s, background 600 s off":
            (*burst, 600.0, args.n_burst),
        # The same burst with the background fitted in the burst interval alone.
        "same burst, background fitted in the 60 s alone": (*burst, None, args.n_burst // 2),
    }
    rng = np.random.default_rng(2026)
    report = {"setup_s": t_setup, "load": os.getloadavg(), "cases": {}}
    print(f"setup (detector response, {nodes.size} energies x 3 angles; columns) "
          f"{t_setup:.1f} s")
    for name, (truth, start, expo, t_off, n_real) in cases.items():
        mu = expected_counts(cols, expo, [truth], background=bkg)
        n_det = mu.shape[0]
        src = expected_counts(cols, expo, [truth]).sum()
        names = [p for p in truth.parameters if p != "piv"]
        pulls, pegged, times = [], 0, []
        for _ in range(n_real):
            y = rng.poisson(mu)
            off = {} if t_off is None else {
                "off_counts": rng.poisson(np.broadcast_to(bkg * t_off, (n_det, bkg.size))),
                "off_exposure": t_off}
            t1 = time.time()
            fit = fit_spectra(cols, y, expo, [start], **off)
            times.append(time.time() - t1)
            if fit.pegged[0]:
                pegged += 1
                continue
            m, e = fit.models[0].parameters, fit.errors[0]
            pulls.append([(m[p] - truth.parameters[p]) / e[p] for p in names])
        pulls = np.array(pulls)
        n_ok = len(pulls)
        print(f"\n{name}: source {src:.0f} counts, background {mu.sum() - src:.0f}; "
              f"{n_real} realisations, {pegged} with a pegged parameter (excluded); "
              f"median fit {np.median(times):.2f} s")
        print(f"{'parameter':>10} {'in 1 sigma [2-sigma band]':>34} {'in 1.645 sigma':>30} "
              f"{'mean pull':>10} {'pull std':>9}")
        rows = {}
        for j, p in enumerate(names):
            k1 = int(np.sum(np.abs(pulls[:, j]) < 1.0))
            k9 = int(np.sum(np.abs(pulls[:, j]) < 1.645))
            lo1, hi1 = wilson(round(0.6827 * n_ok), n_ok)
            lo9, hi9 = wilson(round(0.90 * n_ok), n_ok)
            rows[p] = {"in1": k1, "in90": k9, "n": n_ok, "mean_pull": float(pulls[:, j].mean()),
                       "std_pull": float(pulls[:, j].std())}
            print(f"{p:>10} {k1:>5}/{n_ok} = {k1 / n_ok:.3f} [{lo1:.3f}, {hi1:.3f}] "
                  f"{k9:>5}/{n_ok} = {k9 / n_ok:.3f} [{lo9:.3f}, {hi9:.3f}] "
                  f"{pulls[:, j].mean():>10.3f} {pulls[:, j].std():>9.3f}")
        report["cases"][name] = {"rows": rows, "pegged": pegged, "n": n_real,
                                 "source_counts": float(src),
                                 "background_counts": float(mu.sum() - src),
                                 "median_fit_s": float(np.median(times))}
    save(report, args.out)


def save(report: dict, out: str | None) -> None:
    """Print the load average now and write ``report`` (with it, ``load_end``) as JSON."""
    report["load_end"] = os.getloadavg()
    print(f"\nload average {report['load_end']}")
    if out:
        with open(out, "w") as f:
            json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
