"""Speed of the energy-resolved response against the Monte Carlo that would otherwise produce
it (issue 23), in the same run, and their agreement.

The survey instrument of docs/spectra.md's calibration: 37 detectors of 5 cm x 5 cm NaI(Tl)
under 3/3/3 cm lead slats 1 m up, one rotation in 60 mask-angle bins (centre mode), 100
channels 50 keV-2.5 MeV (NaI resolution), a source 8 deg off axis with an ``E^-2`` spectrum
over 60 keV-3 MeV.

* **The response**: the detector response tabulated once (64 nodes, 3 angles, 2e4 photons a
  point; shared by every source), then per source :func:`spectral_columns` (the exact
  model's columns at the 64 nodes) and, per spectrum, :meth:`SpectralColumns.rates`.
* **The Monte Carlo**: :func:`rotmod.montecarlo.simulate_channel_counts`, the whole chain
  photon by photon (photons through the 3-D slats into the crystal, an analog detector
  history for each one counted, the resolution drawn per photon), energies drawn from the
  spectrum.  Its rate is measured (median of ``--repeat`` runs of ``--energies`` photons per
  detector and bin) and scaled to the photons that give the response's expected counts to a
  stated precision, from the response's expected counts per photon: *per cell* (detector,
  bin, channel: what a fit uses) 1 % (1e4 counts) in the median cell and in 95 % of the
  cells; *per channel summed over detectors and bins* 1 % in every one of the 100 channels,
  in the median channel, and the response's own precision there (its table's Monte Carlo
  noise).  Those Monte Carlo times are *extrapolated* from the measured rate.  The summed
  criteria assume a Monte Carlo whose photons all have their own energies (Poisson sums);
  the chain here shares each energy among the cells (each cell's counts stay Poisson, their
  sums do not), at the same cost per photon.
* **Agreement** (untimed): 20 more runs of the chain against the response, per cell (Pearson
  chi-square) and per summed channel (errors: the runs' spread and the table's noise, from
  a second table), and with a table at the source's angle (no interpolation in angle).

Both run with one numba thread (``NUMBA_NUM_THREADS=1`` is set below), ``nice``d, on a shared
machine: the load average is recorded.

    nice -n 10 python benchmarks/bench_spectral_response.py \
        --out benchmarks/results/bench_spectral_response.json
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import argparse
import json
import statistics
import subprocess
import time

import numpy as np

from rotmod import Instrument
from rotmod.binning import TimeBinning
from rotmod.energy import EnergyResolution
from rotmod.energy import PowerLaw as PhotonPowerLaw
from rotmod.geometry import DetectorArray, Mask
from rotmod.materials import Material
from rotmod.montecarlo import simulate_channel_counts
from rotmod.response import build_response
from rotmod.sky import SkyGrid
from rotmod.sources.spectra import SpectralColumns, spectral_columns
from rotmod.spectral import PowerLaw
from rotmod.spectral.detector import tabulate_response

THETA, PHI, N_BINS = 8.0, 40.0, 60
CHANNELS = np.geomspace(50.0, 2500.0, 101)
RESOLUTION = EnergyResolution.nai()
MODEL = PowerLaw(1.0, -2.0, 100.0)


def load() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def instrument() -> Instrument:
    hexa = DetectorArray.hexagonal(5.0, rings=3)
    det = DetectorArray(hexa.positions, 5.0, thickness=5.0,
                        material=Material("NaI", density=3.67))
    return Instrument(Mask(3.0, 3.0, 3.0, 100.0), det, rotation_period=60.0)


def expected(cols: SpectralColumns, face_photons: np.ndarray) -> np.ndarray:
    """The response's counts when ``face_photons`` photons of the spectrum (over the nodes)
    cross each detector's face in each bin."""
    area = np.pi * 2.5**2 * np.cos(np.radians(THETA))
    flux = MODEL.node_weights(cols.energies).sum()
    return cols.rates(0, MODEL) * face_photons[:, None, None] / (area * flux)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--energies", type=int, default=3000,
                    help="Monte Carlo photons per detector and bin in each timed run")
    ap.add_argument("--repeat", type=int, default=3, help="timed Monte Carlo runs")
    ap.add_argument("--table-photons", type=int, default=20_000)
    ap.add_argument("--nodes", type=int, default=64, help="true-energy nodes (smoke tests: 4)")
    ap.add_argument("--out", default=None, help="JSON file for the numbers")
    args = ap.parse_args()
    nodes = np.geomspace(60.0, 3000.0, args.nodes)
    inst = instrument()
    out: dict = {"load_start": load(), "numba_threads": os.environ["NUMBA_NUM_THREADS"]}
    print(out["load_start"], flush=True)

    # Warm-up (compilation is not timed): one node, a few photons.
    resp = build_response(inst, SkyGrid.square(4, 1.0), N_BINS, energy=300.0)
    xi = np.degrees(TimeBinning(N_BINS).angles())
    small = tabulate_response(inst.detectors, nodes[:2], [0.0, 10.0], CHANNELS,
                              resolution=RESOLUTION, n_photons=200, seed=0)
    spectral_columns(resp, (THETA, PHI), small)
    simulate_channel_counts(inst, THETA, PHI, nodes[:4], CHANNELS, xi=xi,
                            resolution=RESOLUTION, seed=0)

    t = time.perf_counter()
    table = tabulate_response(inst.detectors, nodes, [0.0, 5.0, 10.0], CHANNELS,
                              resolution=RESOLUTION, n_photons=args.table_photons, seed=1)
    t_table = time.perf_counter() - t
    t = time.perf_counter()
    cols = spectral_columns(resp, (THETA, PHI), table)
    t_cols = time.perf_counter() - t
    rates = []
    for _ in range(21):
        t = time.perf_counter()
        cols.rates(0, MODEL)
        rates.append(time.perf_counter() - t)
    t_rates = statistics.median(rates)
    print(f"table {t_table:.1f} s, columns {t_cols:.1f} s, rates {1e3 * t_rates:.2f} ms",
          flush=True)

    # The Monte Carlo: timed runs, each with its own energies drawn from the spectrum.
    law = PhotonPowerLaw(2.0, nodes[0], nodes[-1])
    runs, counts, face = [], 0, None
    for r in range(args.repeat):
        e = law.draw(np.full(args.energies, nodes[0]), np.full(args.energies, nodes[-1]),
                     np.random.default_rng(100 + r))
        t = time.perf_counter()
        mc = simulate_channel_counts(inst, THETA, PHI, e, CHANNELS, xi=xi,
                                     resolution=RESOLUTION, seed=200 + r)
        runs.append(time.perf_counter() - t)
        counts = counts + mc.counts
        face = mc.face_photons if face is None else face + mc.face_photons
        print(f"MC run {r}: {runs[-1]:.1f} s, {mc.interacting} interacting, "
              f"{mc.counts.sum()} recorded", flush=True)
    t_mc = statistics.median(runs)
    per_energy = t_mc / args.energies              # s per photon in every detector and bin
    n_det = len(inst.detectors)
    incident = n_det * N_BINS * args.energies / t_mc   # photons on the faces' discs per s

    # Precision: photons per detector and bin for 1e4 counts in every (in the median)
    # summed channel, from the response's expected counts per photon.
    mu = expected(cols, face)
    per_photon = mu.sum(axis=(0, 1)) / (args.repeat * args.energies)
    need_all = 1e4 / per_photon.min()
    need_median = 1e4 / np.median(per_photon)
    t_all, t_median = need_all * per_energy, need_median * per_energy
    # Per cell (detector, bin, channel), what a fit uses: 1 % in the median cell and in 95 %
    # of the cells that expect any counts.
    cell = (mu / (args.repeat * args.energies))[mu > 0]
    need_cell_median = 1e4 / np.median(cell)
    need_cell_95 = 1e4 / np.percentile(cell, 5)
    t_resp_source = t_cols + t_rates

    # Agreement, untimed: 20 more runs of the chain, each with its own energies.  A cell's
    # counts are Poisson (each photon of a cell has its own energy), but the photons of one
    # energy in different cells share it, so a sum over cells has more than Poisson variance:
    # its error is the spread of the 20 runs' sums.  The table's own noise: a second table
    # (another seed); the redistribution's interpolation in angle: a table at the source's
    # angle itself (the columns do not depend on the table).
    n_agree, batch = 20, max(args.energies // 3, 1)
    sums, cells, face_a = [], 0, 0.0
    for r in range(n_agree):
        e = law.draw(np.full(batch, nodes[0]), np.full(batch, nodes[-1]),
                     np.random.default_rng(300 + r))
        mc = simulate_channel_counts(inst, THETA, PHI, e, CHANNELS, xi=xi,
                                     resolution=RESOLUTION, seed=400 + r)
        sums.append(mc.counts.sum(axis=(0, 1)))
        cells = cells + mc.counts
        face_a = face_a + mc.face_photons
    sums = np.array(sums, dtype=float)
    summed = sums.sum(axis=0)
    mc_rel = np.sqrt(n_agree) * sums.std(axis=0, ddof=1) / np.where(summed > 0, summed, 1)
    mu_a = expected(cols, face_a)
    mu_sum = mu_a.sum(axis=(0, 1))
    ok = mu_a >= 5
    pull_cell = (cells[ok] - mu_a[ok]) / np.sqrt(mu_a[ok])
    table2 = tabulate_response(inst.detectors, nodes, [0.0, 5.0, 10.0], CHANNELS,
                               resolution=RESOLUTION, n_photons=args.table_photons, seed=2)
    at_angle = tabulate_response(inst.detectors, nodes, [THETA], CHANNELS,
                                 resolution=RESOLUTION, n_photons=args.table_photons, seed=3)

    def summed_with(table) -> np.ndarray:
        c = SpectralColumns(cols.columns, table.matrix_at(THETA)[:, None], cols.energies,
                            cols.channel_edges, cols.theta)
        return expected(c, face_a).sum(axis=(0, 1))

    mu2_sum, mu_angle = summed_with(table2), summed_with(at_angle)
    table_rel = np.abs(mu2_sum - mu_sum) / (mu2_sum + mu_sum) * np.sqrt(2)   # one table's
    table_noise = float(np.sqrt(np.mean(table_rel**2)))
    err = np.sqrt(mc_rel**2 + table_noise**2)
    pull_c = (summed / mu_sum - 1.0) / err
    pull_angle = (summed / mu_angle - 1.0) / err
    # Photons per cell for the Monte Carlo's summed channels to be as precise as the
    # response's own (its table's noise), for a Monte Carlo whose photons all have their own
    # energies (Poisson sums), in the median channel.
    need_table = 1.0 / (table_noise**2 * np.median(per_photon))
    out.update({
        "instrument": "37 x 5x5 cm NaI, Pb slats 3/3/3 cm at 1 m",
        "theta": THETA, "phi": PHI, "bins": N_BINS, "channels": CHANNELS.size - 1,
        "nodes": nodes.size, "table_photons": args.table_photons,
        "t_table_s": t_table, "t_columns_s": t_cols, "t_rates_s": t_rates,
        "t_response_per_source_s": t_resp_source,
        "mc_energies_per_run": args.energies, "mc_runs_s": runs, "mc_median_s": t_mc,
        "mc_incident_photons_per_s": incident,
        "mc_s_per_photon_per_cell": per_energy,
        "counts_per_photon_per_cell_min_channel": float(per_photon.min()),
        "counts_per_photon_per_cell_median_channel": float(np.median(per_photon)),
        "photons_per_cell_1pct_every_channel": float(need_all),
        "photons_per_cell_1pct_median_channel": float(need_median),
        "mc_s_1pct_every_channel_extrapolated": float(t_all),
        "mc_s_1pct_median_channel_extrapolated": float(t_median),
        "photons_per_cell_1pct_median_cell": float(need_cell_median),
        "photons_per_cell_1pct_95pct_cells": float(need_cell_95),
        "mc_s_1pct_median_cell_extrapolated": float(need_cell_median * per_energy),
        "mc_s_1pct_95pct_cells_extrapolated": float(need_cell_95 * per_energy),
        "photons_per_cell_table_noise_median_channel": float(need_table),
        "mc_s_table_noise_median_channel_extrapolated": float(need_table * per_energy),
        "ratio_every_channel_vs_columns": float(t_all / t_resp_source),
        "ratio_median_channel_vs_columns": float(t_median / t_resp_source),
        "ratio_every_channel_vs_table_and_columns": float(t_all / (t_table + t_resp_source)),
        "ratio_median_channel_vs_table_and_columns": float(
            t_median / (t_table + t_resp_source)),
        "agreement_runs": n_agree, "agreement_photons_per_cell": n_agree * batch,
        "summed_channel_chi2_per_dof": float(pull_c @ pull_c / pull_c.size),
        "summed_channel_max_pull": float(np.abs(pull_c).max()),
        "summed_channel_total_ratio_mc_over_response": float(summed.sum() / mu_sum.sum()),
        "summed_channel_mc_rel_median": float(np.median(mc_rel)),
        "summed_channel_poisson_rel_median": float(np.median(1 / np.sqrt(summed))),
        "summed_channel_table_noise_rel": table_noise,
        "summed_channel_chi2_per_dof_table_at_angle": float(
            pull_angle @ pull_angle / pull_angle.size),
        "summed_channel_max_pull_table_at_angle": float(np.abs(pull_angle).max()),
        "channel_mc_counts": summed.tolist(), "channel_mc_rel_error": mc_rel.tolist(),
        "channel_response": mu_sum.tolist(), "channel_response_table2": mu2_sum.tolist(),
        "channel_response_table_at_angle": mu_angle.tolist(),
        "cell_chi2_per_dof": float(pull_cell @ pull_cell / pull_cell.size),
        "cell_dof": int(pull_cell.size),
        "cell_max_pull": float(np.abs(pull_cell).max()),
        "mc_counts_total_timed": int(counts.sum()),
        "load_end": load(),
    })
    for k, v in out.items():
        if not k.startswith("channel_"):
            print(f"{k}: {v}")
    if args.out:
        with open(args.out, "w", encoding="utf-8") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
