"""Latency of the burst chain (issue 22): event file -> position, region map and summary.

300 s of events around a burst (the survey instrument: 37 detectors of 5 cm under 3/3/3 cm
lead 1 m up, a 4 s turn, 1.5 counts/s/detector of background, 300 keV; a Norris pulse 30 deg
off axis) are written to a FITS file.  Timed, from reading the file to writing the summary
and the HEALPix probability map:

* **ours, cold**: nothing prepared (the folded response of the attitude is computed here);
* **ours, warm**: the responses of the attitude (the search map's Radon tables, the folded
  response of the fits) computed before the trigger, as a flight system would (``cache``);
* **the straightforward way**: the likelihood of a source in every pixel of a HEALPix grid at
  the final resolution (pixels a quarter of the 90 % radius) over the searched cone, in the
  fine bins.  Timed on a random sample of the cone's pixels and scaled to all of them (a full
  run would take hours).

Prints a table with medians over ``--repeat`` runs and the machine's load.

    python benchmarks/bursts_latency.py            # writes benchmarks/results/bursts_latency.txt
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import astropy.units as u
import numpy as np

from rotmod import io
from rotmod.bursts import analyse_burst, norris_pulse, search, simulate_burst
from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.io.regions import write_probability_map
from rotmod.sky import Attitude
from rotmod.sky.healpix import HealpixGrid
from rotmod.sources.fitting import SourceFitter
from rotmod.sources.model import SkyModel
from rotmod.sources.tsmap import null_state, scan_test_source

ROOT = Path(__file__).resolve().parent.parent
RADIUS = 65.0


def chain(path: Path, out: Path, cache: dict | None) -> tuple[float, object]:
    """Read, search, analyse, write: the wall time and the burst."""
    t = time.perf_counter()
    events = io.read(path)
    cand = max(search(events).candidates, key=lambda c: c.significance)
    burst = analyse_burst(events, cand, energy=300.0, radius=RADIUS, cache=cache)
    write_probability_map(burst.position.probability_map(), out / "prob.fits",
                          overwrite=True)
    (out / "summary.txt").write_text(burst.summary("GRB"))
    return time.perf_counter() - t, burst


def straightforward(burst, sample: int, rng: np.random.Generator) -> tuple[float, int, int]:
    """Seconds per pixel of the full-resolution likelihood grid (on ``sample`` pixels of the
    cone), and the grid's nside and pixel count."""
    pos = burst.position
    fitter_response = pos.response
    att = fitter_response.grid.attitude
    r90 = pos.region.radius(0.9)
    nside = 1
    while 58.6 / nside > r90 / 4.0:
        nside *= 2
    grid = HealpixGrid(nside, att.ra, att.dec, RADIUS, att)
    data = pos.counts.data(
        burst.background.counts(pos.counts.edges) / np.diff(pos.counts.edges)[None, :])
    fitter = SourceFitter(fitter_response, data)
    state = null_state(fitter, SkyModel())
    th, ph = grid.directions()
    pick = rng.choice(grid.size, size=min(sample, grid.size), replace=False)
    coords = att.to_sky(th[pick], ph[pick])
    t = time.perf_counter()
    scan_test_source(fitter, state, fitter.columns_on_bins(coords), 0.0, 0.0)
    return (time.perf_counter() - t) / pick.size, nside, grid.size


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--sample", type=int, default=200)
    p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" /
                   "bursts_latency.txt")
    args = p.parse_args()
    inst = Instrument(Mask(3, 3, 3, 100), DetectorArray.hexagonal(5, rings=3),
                      rotation_period=4.0)
    att = Attitude(30.0, 40.0, 10.0)
    truth = att.to_sky(30 * u.deg, 70 * u.deg)
    events = simulate_burst(inst, truth, lambda t: norris_pulse(t, 100.0, 0.5, 3.0, 10.0),
                            t_start=0, t_stop=300, background=1.5, energy=300.0,
                            attitude=att, seed=1)
    lines = []

    def say(text: str) -> None:
        print(text, flush=True)
        lines.append(text)

    with tempfile.TemporaryDirectory() as tmp:
        tmpd = Path(tmp)
        path = tmpd / "events.fits"
        io.write(events, path)
        cold, warm, loads = [], [], []
        burst = None
        for _ in range(args.repeat):
            loads.append(os.getloadavg()[0])
            cold.append(chain(path, tmpd, None)[0])
            cache: dict = {}
            chain(path, tmpd, cache)            # prepares the attitude's folded response
            loads.append(os.getloadavg()[0])
            dt, burst = chain(path, tmpd, cache)
            warm.append(dt)
        per_pixel, nside, n_pix = straightforward(burst, args.sample,
                                                  np.random.default_rng(0))
    naive = per_pixel * n_pix
    say("Burst latency (issue 22): event file of 300 s -> position, region map, summary")
    say(f"  survey instrument (37 x 5 cm, b/L 1.72 deg, 4 s turn), 1.5 counts/s/detector, "
        f"{len(events)} events; burst 30 deg off axis, sqrt TS "
        f"{burst.position.sqrt_ts:.1f}, r90 {burst.position.region.radius(0.9):.2f} deg")
    say(f"  {platform.python_version()} on {os.cpu_count()} cores; load average (1 min) "
        f"median {np.median(loads):.2f}, max {max(loads):.2f}; {args.repeat} runs each")
    say("")
    say("| | median (s) | min (s) | max (s) |")
    say("|---|---|---|---|")
    say(f"| ours, cold (response computed here) | {np.median(cold):.1f} | {min(cold):.1f} | "
        f"{max(cold):.1f} |")
    say(f"| ours, warm (attitude's response prepared) | {np.median(warm):.1f} | "
        f"{min(warm):.1f} | {max(warm):.1f} |")
    say(f"| straightforward: TS of every pixel at nside {nside} ({n_pix} pixels in the "
        f"{RADIUS:g} deg cone), fine bins; {per_pixel * 1e3:.1f} ms/pixel on {args.sample} "
        f"pixels, scaled | {naive:.0f} | | |")
    say("")
    say(f"  ratio straightforward / ours warm: {naive / np.median(warm):.0f}x")
    args.out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
