"""Where the truth stands among the search's peaks, for draws of the burst calibration.

For each draw (the calibration's seed and set-up, ``benchmarks/bursts_calibration.py``) the
burst is simulated, searched and analysed up to the first score map's distinct peaks (the
pulses seen from no position; ``localise_burst`` then makes a second map, weighted by the
pulses seen from the likeliest of them, which this diagnostic predates and leaves out), then
stopped (no climbs: seconds per burst instead of minutes).  Printed per draw, one JSON line:

* the peak nearest the truth: its distance (deg), its place among the peaks by score and by
  exact likelihood at the pixel centre, and its TS below the likeliest peak's
  (``dts_nearest``) -- ``localise_burst`` climbs the ``FINE_FITS`` likeliest and any other
  within ``MODE_DTS + CLIMB_MARGIN`` of the best, at most ``MAX_CLIMBS``;
* the TS of the likeliest peak's pixel above the truth's exact position, the pulses refined
  there from the search's (``dts_truth_pixelfree``; < 0: the truth is likelier than every
  pixel centre);
* every peak's TS below the likeliest, and its distance to the truth.

The likelihoods are those of the search: its bins, its response, the pulses refined from
the search's as seen from each position.  The peaks are captured from ``localise_burst``'s
frame when it calls ``_peaks`` (a diagnostic of the pipeline as it is, without a hook in the
library for it).

    NUMBA_NUM_THREADS=1 PYTHONPATH=src python benchmarks/bursts_peaks_diagnostic.py 4,17,21,23
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import bursts_calibration as bc

from rotmod.bursts import localisation
from rotmod.bursts.analysis import analyse_burst
from rotmod.bursts.inject import simulate_burst
from rotmod.bursts.measure import true_durations
from rotmod.bursts.search import search
from rotmod.sources.fitting import SourceFitter
from rotmod.sources.model import PointSource, SkyModel


class _Stop(Exception):
    """Raised once the peaks are known: the rest of the analysis is not needed."""


def main(indices: list[int]) -> None:
    frame: dict = {}
    peaks_of = localisation._peaks

    def capture(th, ph, values, apart, n):
        found = peaks_of(th, ph, values, apart, n)
        frame.update(sys._getframe(1).f_locals, peaks=found)
        raise _Stop

    localisation._peaks = capture
    inst, att = bc.setup()
    for i in indices:
        tr = bc.draw_truth(bc.SEED, i)
        lc = bc.light_curve(tr["pulses"])
        pos = att.to_sky(tr["theta"], tr["phi"])
        ev = simulate_burst(inst, pos, lc, t_start=bc.T_START, t_stop=bc.T_STOP,
                            background=bc.BACKGROUND, energy=bc.ENERGY, attitude=att,
                            seed=tr["sim_seed"])
        true = true_durations(lc, *bc.TRUTH_WINDOW)
        end = true.t90_start + true.t90 + 1.0
        over = [c for c in search(ev).candidates
                if c.interval[1] > bc.T_BURST - 1.0 and c.interval[0] < end]
        if not over:
            print(json.dumps({"index": i, "detected": False}), flush=True)
            continue
        t = time.perf_counter()
        try:
            analyse_burst(ev, max(over, key=lambda c: c.significance), energy=bc.ENERGY,
                          radius=bc.RADIUS, light_curve=True)
        except _Stop:
            pass
        coords = frame["score"].grid.sky_coords()[frame["peaks"]]

        def loglike(c, f=frame):
            src = PointSource(c)
            seen = localisation.burst_pulses(f["light_curve"], f["counts"], f["background"],
                                             f["unit"], src, f["pulses"])
            fitter = SourceFitter(f["unit"].with_weight(seen.shape(f["counts"].edges)),
                                  f["data"])
            return fitter.maximise(SkyModel((src,)))[1].loglike

        ll = np.array([loglike(c) for c in coords])
        by_ll = {int(k): j for j, k in enumerate(np.argsort(ll)[::-1])}
        sep = coords.separation(pos).deg
        near = int(np.argmin(sep))
        print(json.dumps({
            "index": i, "n_peaks": len(coords), "sep_nearest_peak": float(sep[near]),
            "nearest_score_rank": near, "nearest_ll_rank": by_ll[near],
            "dts_nearest": float(2 * (ll.max() - ll[near])),
            "dts_truth_pixelfree": float(2 * (ll.max() - loglike(pos))),
            "dts_peaks": [float(2 * (ll.max() - v)) for v in ll],
            "seps": [float(s) for s in sep], "time": time.perf_counter() - t}), flush=True)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: bursts_peaks_diagnostic.py I,J,... (draw indices)")
    main([int(v) for v in sys.argv[1].split(",")])
