"""Calibration of forward-folded fits of a counts spectrum (rotmod.spectral.fit_spectrum).

Poisson injections through a scintillator-like response (Gaussian redistribution of NaI's
width, 100 cm^2, 48 channels from 30 keV to 2 MeV); fits started away from the truth; pulls
``(fit - truth) / error`` per parameter: the fraction within 1 and 1.645 sigma, the mean pull
(bias in units of the error) and the pulls' width.  Fits with a pegged parameter are counted
and left out of the pulls (said in the output).  Results: docs/spectra.md.

    python benchmarks/spectra_fit_calibration.py [--n 500] [--n-band 200]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from scipy.special import erf

from rotmod.spectral import Band, CountsSpectrum, PowerLaw, SpectralResponse, fit_spectrum


def gaussian_response(n_e: int = 120, n_c: int = 48) -> SpectralResponse:
    """The response of tests/spectral/test_spectrum.py (Gaussian redistribution, 80 %)."""
    ee = np.geomspace(20.0, 3000.0, n_e + 1)
    ce = np.geomspace(30.0, 2000.0, n_c + 1)
    ec = np.sqrt(ee[:-1] * ee[1:])
    sig = (0.04 * ec * (ec / 662.0) ** -0.5)[:, None] * np.sqrt(2.0)
    m = 0.5 * (erf((ce[None, 1:] - ec[:, None]) / sig) - erf((ce[None, :-1] - ec[:, None]) / sig))
    return SpectralResponse(ee, ce, 0.8 * m, np.full(n_e, 100.0))


def run(name, truth, start, n, make, rng) -> None:
    names = [p for p in truth.parameters if p != "piv"]
    pulls, pegged, t0 = [], 0, time.time()
    for _ in range(n):
        fit = fit_spectrum(make(rng), start)
        if fit.pegged:
            pegged += 1
            continue
        pulls.append([(fit.model.parameters[p] - truth.parameters[p]) / fit.errors[p]
                      for p in names])
    p = np.array(pulls)
    print(f"\n{name}: {n} realisations, {pegged} pegged (left out), "
          f"{(time.time() - t0) / n * 1e3:.0f} ms per fit")
    print(f"{'parameter':>10} {'within 1 sigma':>15} {'within 1.645':>13} {'mean pull':>10} "
          f"{'width':>7}")
    for j, q in enumerate(names):
        print(f"{q:>10} {np.mean(np.abs(p[:, j]) < 1):>15.3f} "
              f"{np.mean(np.abs(p[:, j]) < 1.645):>13.3f} {p[:, j].mean():>10.3f} "
              f"{p[:, j].std():>7.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--n-band", type=int, default=200)
    args = ap.parse_args()
    r = gaussian_response()
    pl = PowerLaw(1e-4, -2.0)
    mu = r.fold(pl, 1e4)
    run("E^-2, ~4e4 counts, no background", pl, PowerLaw(2e-4, -1.5), args.n,
        lambda g: CountsSpectrum(g.poisson(mu), 1e4, r), np.random.default_rng(100))
    run("same with a measured background (W statistic, BACKSCAL 2)", pl, PowerLaw(2e-4, -1.5),
        args.n, lambda g: CountsSpectrum(g.poisson(mu + 20.0), 1e4, r, CountsSpectrum(
            g.poisson(np.full(48, 40.0)), 1e4, backscal=2.0)), np.random.default_rng(101))
    band = Band(5e-3, -0.9, 300.0, -2.5)
    mu_b = r.fold(band, 20.0)
    run("Band (alpha -0.9, xp 300 keV, beta -2.5), ~1e4 counts", band,
        Band(3e-3, -1.2, 400.0, -2.2), args.n_band,
        lambda g: CountsSpectrum(g.poisson(mu_b), 20.0, r), np.random.default_rng(7))
    print(f"\nload average {os.getloadavg()}")


if __name__ == "__main__":
    main()
