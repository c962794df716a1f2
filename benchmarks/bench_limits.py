"""The rates behind rotmod's time estimates (``rotmod.limits.RATES``), and how good the
estimates are: estimated against measured wall time for each budgeted request.

Run ``python benchmarks/bench_limits.py [--repeat 3]``.  Each row is a request of a few
seconds: the estimate ``rotmod.limits.check_time`` makes before it starts (from ``RATES``,
or, for the Radon table and the bootstrap, from the rate measured at the time) beside the
median measured wall time, and their ratio; then the rate each ``RATES`` entry implies.
The load average is printed (the machine is shared).  Results go to docs/reliability.md
("Time: estimated before it is spent").
"""

from __future__ import annotations

import argparse
import logging
import os
import statistics
import time

import numpy as np

import rotmod.limits as limits
from rotmod import Instrument
from rotmod.design import scan_designs
from rotmod.montecarlo import simulate_profiles
from rotmod.reconstruction import reconstruct
from rotmod.response import RadonResponse, build_response
from rotmod.sky import AttitudeTable, SkyGrid


class _Estimates(logging.Handler):
    """Collects the estimates check_time announces (ANNOUNCE_SECONDS set to 0 here)."""

    def __init__(self) -> None:
        super().__init__()
        self.seconds: list[float] = []

    def emit(self, record: logging.LogRecord) -> None:
        _, _, units, _, per_s = record.args  # check_time's message: units at per_s /s
        self.seconds.append(units / per_s)


def _median(fn, repeat: int) -> float:
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    limits.ANNOUNCE_SECONDS = 0.0  # every estimate is logged, and collected
    est = _Estimates()
    logging.getLogger("rotmod.limits").addHandler(est)
    logging.getLogger("rotmod.limits").setLevel(logging.INFO)
    inst = Instrument.paper()
    design = dict(detector_diameter=4.0, height=100.0, slat_width=np.linspace(2, 8, 7),
                  slat_gap=np.linspace(2, 8, 7), thickness=2.0, energies=(122.0, 662.0))
    att = AttitudeTable([0.0, 100.0, 200.0], [0.0, 10.0, 20.0], [0.0, 5.0, 10.0], [0.0] * 3)
    resp = build_response(inst, SkyGrid((9, 9), 1.0), 64, energy=122)
    counts = np.random.default_rng(1).poisson(200 * resp.forward(np.ones(81)) + 20)
    main_run = _median(lambda: reconstruct(resp, counts, "mlem", max_iter=50), args.repeat)
    requests = {
        "design 49 x 2 x 5000 angles x 12 sources": (
            "design_values", lambda: scan_designs(**design, n_angles=5000)),
        "simulate_profiles 10 x 100 x 1e4 photons": (
            "mc_photons", lambda: simulate_profiles(inst, np.linspace(0, 9, 10), np.zeros(10),
                                                    np.arange(100.0), energy=662,
                                                    n_photons=10**4, seed=1)),
        "AttitudeTable.intervals 2000 pieces": (
            "attitude_pieces", lambda: att.intervals(0, 200, 0.1)),
        "RadonResponse table, 60 deg field": (
            None, lambda: RadonResponse(inst, SkyGrid.square(60, 1.0), 64, 662)),
        "bootstrap 20 replicas (mlem, 50 it)": (
            None, lambda: reconstruct(resp, counts, "mlem", max_iter=50,
                                      uncertainty="bootstrap", n_boot=20)),
    }
    print(f"load average {os.getloadavg()[0]:.2f} (2 cores)")
    print(f"{'request':44s} {'estimate':>9s} {'measured':>9s} {'ratio':>6s}")
    for name, (rate, fn) in requests.items():
        fn()  # compile, warm caches
        est.seconds.clear()
        wall = _median(fn, args.repeat)
        e = statistics.median(est.seconds) if est.seconds else float("nan")
        if name.startswith("bootstrap"):
            wall -= main_run  # the estimate covers the replicas, not the main run
        print(f"{name:44s} {e:9.3f} {wall:9.3f} {wall / e:6.2f}"
              + (f"   RATES[{rate!r}] = {limits.RATES[rate]:.3g}/s" if rate else ""))
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
