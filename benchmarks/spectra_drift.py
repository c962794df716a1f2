"""The energy-resolved response of a drifting observation: cost and the hat-weight identity at
a realistic small size (issue 23).

A zenith-pointed gondola at latitude 35 deg (axis at Dec 35) turning once a minute, whose axis
drifts past a source in 8 intervals; two cases: 1.25 deg of RA per interval past a source at
Dec 37 (near the zenith), and 7.5 deg per interval past one at Dec 60 (25-30 deg off axis).
24 mask-angle bins; 7 detectors of 5 cm x 5 cm NaI under 3/3/3 cm lead slats 1 m up; 32
true-energy nodes from 60 keV to 3 MeV, 32 channels, the detector response tabulated at 0, 5,
10, 20, 30 and 40 deg.  Times :func:`spectral_columns` for the drift and for one of its
intervals, and :meth:`SpectralColumns.rates`; compares the drift's rates with the intervals'
single-attitude columns (each with ``matrix_at`` at its own angle) summed with their weights,
and with the redistribution frozen at the source's mean angle.  Results: docs/spectra.md.

    NUMBA_NUM_THREADS=1 python benchmarks/spectra_drift.py
"""

from __future__ import annotations

import dataclasses
import time

import astropy.units as u
import numpy as np
from astropy.coordinates import SkyCoord

from rotmod import Instrument
from rotmod.energy import EnergyResolution
from rotmod.geometry import DetectorArray, Mask
from rotmod.materials import Material
from rotmod.response import build_response
from rotmod.response.drift import drift_response
from rotmod.sky import Attitude, CelestialGrid
from rotmod.sources.spectra import SpectralColumns, spectral_columns
from rotmod.spectral import PowerLaw
from rotmod.spectral.detector import tabulate_response

N_T, N_K, STEP = 24, 8, 300.0


def main() -> None:
    for dec, step_deg in ((37.0, 1.25), (60.0, 7.5)):
        case(dec, step_deg)


def case(dec: float, step_deg: float) -> None:
    """A source at (RA 5 deg, ``dec``), the axis at Dec 35 moving ``step_deg`` of RA per
    interval (1.25 deg: 5 minutes of a zenith-pointed gondola's drift; 7.5 deg: 30 min)."""
    print(f"\n--- source at Dec {dec:g}, {step_deg:g} deg of RA per interval")
    hexa = DetectorArray.hexagonal(5.0, rings=1)
    det = DetectorArray(hexa.positions, 5.0, thickness=5.0,
                        material=Material("NaI", density=3.67))
    inst = Instrument(Mask(3.0, 3.0, 3.0, 100.0, material=Material("Pb")), det,
                      rotation_period=60.0)
    nodes = np.geomspace(60.0, 3000.0, 32)
    table = tabulate_response(det, nodes, [0.0, 5.0, 10.0, 20.0, 30.0, 40.0],
                              np.geomspace(50.0, 2500.0, 33),
                              resolution=EnergyResolution.nai(), n_photons=2000, seed=1)
    intervals = [(k * STEP, (k + 1) * STEP, Attitude(5.0 + step_deg * (k - 3.5), 35.0))
                 for k in range(N_K)]
    grid = CelestialGrid((3, 3), 2.0, 5.0, dec, Attitude(5.0, dec))
    source = SkyCoord([5.0] * u.deg, [dec] * u.deg)
    theta = [att.to_instrument(source)[0].to_value(u.deg)[0] for *_, att in intervals]
    print(f"source's zenith angle over the intervals: {np.round(theta, 2)} deg")
    drift = drift_response(inst, grid, N_T, intervals, energy=300.0)
    t0 = time.perf_counter()
    cols = spectral_columns(drift, source, table)
    t_drift = time.perf_counter() - t0
    singles, t_one = [], []
    for *_, att in intervals:
        one = build_response(inst, dataclasses.replace(grid, attitude=att), N_T, energy=300.0,
                             dtype=np.float64)
        t0 = time.perf_counter()
        singles.append(spectral_columns(one, source, table))
        t_one.append(time.perf_counter() - t0)
    model = PowerLaw(1e-2, -2.0)
    want = sum(w[None, :, None] * s.rates(0, model)
               for (w, _), s in zip(drift.components(), singles, strict=True))
    got = cols.rates(0, model)
    n_rep = 51
    t0 = time.perf_counter()
    for _ in range(n_rep):
        cols.rates(0, model)
    t_rates = (time.perf_counter() - t0) / n_rep
    t0 = time.perf_counter()
    for _ in range(n_rep):
        singles[0].rates(0, model)
    t_rates1 = (time.perf_counter() - t0) / n_rep
    # What the angle nodes buy: the same columns with the redistribution frozen at the
    # source's mean angle over the drift.
    frozen = SpectralColumns(cols.columns.sum(axis=1, keepdims=True),
                             table.matrix_at([np.mean(theta)])[:, None], cols.energies,
                             cols.channel_edges, np.array([[np.mean(theta)]]))
    per_channel = want.sum(axis=(0, 1))
    shift = np.abs(frozen.rates(0, model).sum(axis=(0, 1)) / per_channel - 1.0)
    print(f"redistribution frozen at the mean angle {np.mean(theta):.2f} deg: per-channel "
          f"rates off by up to {shift[per_channel > 1e-3 * per_channel.max()].max():.1e}")
    print(f"angle nodes: {cols.theta[0]} deg")
    print(f"drift vs the intervals' weighted sum: max |diff| / max = "
          f"{np.abs(got - want).max() / want.max():.2e}")
    print(f"spectral_columns: drift ({N_K} intervals) {t_drift:.2f} s, one interval "
          f"{np.median(t_one):.2f} s (median of {N_K})")
    print(f"rates: drift ({cols.columns.shape[1]} angle nodes) {t_rates * 1e3:.2f} ms, "
          f"one attitude {t_rates1 * 1e3:.2f} ms")


if __name__ == "__main__":
    main()
