"""The energy-resolved response against the whole chain photon by photon, at high statistics
(issue 23; docs/spectra.md, "Against the whole chain, photon by photon").

The instrument of tests/sources/test_spectral_chain.py (7 detectors of 5 cm x 5 cm NaI under
lead slats 3 cm wide, 3 cm apart, 1 cm thick, 1 m up; a source 10 deg off axis; 8 mask-angle
bins at their centres; 6 channels 120 keV-2 MeV, NaI resolution).  Counts summed over
detectors and bins per channel, where the chain's error is 0.1-0.5 %: the
response's ratio to the chain and the error of that ratio (the chain's Poisson error and the
table's own Monte Carlo noise, measured as half the spread between two tables of different
seeds), for a 662 keV line on a node and between nodes 3.3 % and 7 % apart, and for an
``E^-2`` continuum (200 keV-2 MeV) with nodes 2.4 %, 4.9 % and 10 % apart.  The chain runs
20 times (1e5 photons per detector and bin in all); its error on a channel sum is the spread
of the runs' sums, not Poisson: its photons of one energy in different cells share it.
Per-cell Pearson chi-square (detector, bin, channel) too.  First, the test's two checks
with 20 seeds of the chain (the spread its tolerances rest on).

    nice -n 10 python benchmarks/spectra_chain.py > benchmarks/results/spectra_chain.txt
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from rotmod.binning import TimeBinning
from rotmod.response import build_response
from rotmod.sky import SkyGrid
from rotmod.sources.spectra import spectral_columns
from rotmod.spectral.detector import tabulate_response

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "sources"))
import test_spectral_chain as T  # the test's instrument and helpers


def compare(label: str, resp, nodes, n_table: int, model, runs: list) -> None:
    """The response with ``nodes`` (two tables of different seeds) against the chain's
    ``runs`` (independent :class:`ChannelCounts`)."""
    counts = sum(r.counts for r in runs)
    face = sum(r.face_photons for r in runs)
    mus = []
    for seed in (1, 2):
        table = tabulate_response(T._instrument().detectors, nodes, [T.THETA], T.CHANNELS,
                                  resolution=T.RESOLUTION, n_photons=n_table, seed=seed)
        mus.append(T._scaled(spectral_columns(resp, (T.THETA, T.PHI), table), model, face))
    mu = 0.5 * (mus[0] + mus[1])
    s0, s1 = mus[0].sum(axis=(0, 1)), mus[1].sum(axis=(0, 1))
    ok = s0 + s1 >= 200.0          # channels expecting counts (not a line's far tail)
    sums = np.array([r.counts.sum(axis=(0, 1)) for r in runs], dtype=float)[:, ok]
    s_mc, s_mu = sums.sum(axis=0), 0.5 * (s0 + s1)[ok]
    ratio = s_mc / s_mu
    # Error of the ratio: the chain's, the spread of its independent runs' sums (photons of
    # one energy in different cells share it: the sums are not Poisson), and the mean
    # table's (|difference| / 2 estimates one table's error; the mean has 1/sqrt(2) of it).
    mc_rel = np.sqrt(len(runs)) * sums.std(axis=0, ddof=1) / s_mc
    table_rel = np.abs(s0[ok] - s1[ok]) / (s0[ok] + s1[ok]) / np.sqrt(2)
    err = np.sqrt(mc_rel**2 + table_rel**2)
    pull = (ratio - 1.0) / err
    chi2, dof, worst = T.pearson(counts, mu)
    print(f"{label}: nodes {len(nodes)} ({100 * (nodes[1] / nodes[0] - 1):.1f} % apart), "
          f"table {n_table} photons a node")
    print("  channel ratio chain/response: " + ", ".join(
        f"{r:.4f} +- {e:.4f}" for r, e in zip(ratio, err, strict=True)))
    print(f"  (chain's error {np.round(mc_rel, 4).tolist()}, Poisson "
          f"{np.round(1 / np.sqrt(s_mc), 4).tolist()})")
    print(f"  channel pulls: {np.round(pull, 2).tolist()}, chi2/dof {pull @ pull / pull.size:.2f}")
    print(f"  cells: chi2/dof {chi2 / dof:.3f} ({dof} cells), max |pull| {worst:.2f}",
          flush=True)


def chain(inst, xi, energies: list[np.ndarray], seed: int) -> list:
    """Independent runs of the chain, one per array of energies."""
    return [T.simulate_channel_counts(inst, T.THETA, T.PHI, e, T.CHANNELS, xi=xi,
                                      resolution=T.RESOLUTION, seed=seed + j)
            for j, e in enumerate(energies)]


def seeds(inst, xi, resp, n: int) -> None:
    """The test's two checks (its tables, its photons) repeated with ``n`` seeds of the
    chain: the spread of chi2/dof and of the largest pull that its tolerances rest on, and
    the modulation frozen at 662 keV."""
    line_table = tabulate_response(inst.detectors, [650.0, 672.0], [T.THETA], T.CHANNELS,
                                   resolution=T.RESOLUTION, n_photons=100_000,
                                   seed=T.SEEDS["line_table"])
    pl_table = tabulate_response(inst.detectors, T.NODES, [T.THETA], T.CHANNELS,
                                 resolution=T.RESOLUTION, n_photons=10_000,
                                 seed=T.SEEDS["pl_table"])
    lc = spectral_columns(resp, (T.THETA, T.PHI), line_table)
    pc = spectral_columns(resp, (T.THETA, T.PHI), pl_table)
    k = int(np.argmin(np.abs(T.NODES - T.LINE)))
    c = pc.columns
    frozen = T.SpectralColumns(
        c[:, :, k:k + 1] * (c.sum(axis=4, keepdims=True)
                            / c[:, :, k:k + 1].sum(axis=4, keepdims=True)),
        pc.redistribution, pc.energies, pc.channel_edges, pc.theta)
    line, pl = T.Gaussian(1.0, T.LINE, 0.01), T.PowerLaw(1.0, -2.0, 100.0)
    law = T.PhotonPowerLaw(2.0, T.NODES[0], T.NODES[-1])
    rows = []
    for s in range(100, 100 + n):
        mc = T.simulate_channel_counts(inst, T.THETA, T.PHI, np.full(20_000, T.LINE),
                                       T.CHANNELS, xi=xi, resolution=T.RESOLUTION, seed=s)
        a = T.pearson(mc.counts, T._scaled(lc, line, mc.face_photons))
        e = law.draw(np.full(24_000, T.NODES[0]), np.full(24_000, T.NODES[-1]),
                     np.random.default_rng(s))
        mc = T.simulate_channel_counts(inst, T.THETA, T.PHI, e, T.CHANNELS, xi=xi,
                                       resolution=T.RESOLUTION, seed=s + 1000)
        b = T.pearson(mc.counts, T._scaled(pc, pl, mc.face_photons))
        w = T.pearson(mc.counts, T._scaled(frozen, pl, mc.face_photons))
        rows.append((a[0] / a[1], a[2], b[0] / b[1], b[2], w[0] / w[1]))
        print(f"seed {s}: line chi2/dof {rows[-1][0]:.3f} max {a[2]:.2f}; E^-2 chi2/dof "
              f"{rows[-1][2]:.3f} max {b[2]:.2f}; frozen {rows[-1][4]:.2f}", flush=True)
    r = np.array(rows)
    print(f"{n} seeds: line chi2/dof {r[:, 0].min():.2f}-{r[:, 0].max():.2f} (mean "
          f"{r[:, 0].mean():.2f}), max pull {r[:, 1].max():.2f}; E^-2 {r[:, 2].min():.2f}-"
          f"{r[:, 2].max():.2f} (mean {r[:, 2].mean():.2f}), max pull {r[:, 3].max():.2f}; "
          f"frozen {r[:, 4].min():.2f}-{r[:, 4].max():.2f}", flush=True)


def main() -> None:
    print(subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    inst = T._instrument()
    binning = TimeBinning(T.N_TIME)
    xi = np.degrees(binning.angles())
    resp = build_response(inst, SkyGrid.square(4, 1.0), binning, "exact", energy=300.0)
    seeds(inst, xi, resp, 20)
    n_runs, per_run = 20, 5_000          # 1e5 photons per detector and bin
    runs = chain(inst, xi, [np.full(per_run, T.LINE)] * n_runs, 1000)
    print(f"line 662 keV: {n_runs} x {per_run} photons per detector and bin, "
          f"{sum(r.counts.sum() for r in runs)} counts", flush=True)
    line = T.Gaussian(1.0, T.LINE, 0.01)
    for label, nodes in (("on a node", [662.0, 700.0]),
                         ("between nodes, 3.3 %", [650.0, 672.0]),
                         ("between nodes, 7 %", [640.0, 685.0])):
        compare(f"line {label}", resp, np.array(nodes), 400_000, line, runs)
    law = T.PhotonPowerLaw(2.0, 200.0, 2000.0)
    rng = np.random.default_rng(32)
    runs = chain(inst, xi, [law.draw(np.full(per_run, 200.0), np.full(per_run, 2000.0), rng)
                            for _ in range(n_runs)], 2000)
    print(f"E^-2, 200 keV-2 MeV: {n_runs} x {per_run} photons per detector and bin, "
          f"{sum(r.counts.sum() for r in runs)} counts", flush=True)
    pl = T.PowerLaw(1.0, -2.0, 100.0)
    for n in (96, 48, 24):
        compare("E^-2", resp, np.geomspace(200.0, 2000.0, n), 40_000, pl, runs)
    print(subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())


if __name__ == "__main__":
    main()
