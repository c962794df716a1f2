"""The false-alarm rate of the burst trigger (:func:`rotmod.bursts.search.search`), measured.

Background-only data of the survey instrument -- 37 detectors at 1.5 counts/s each, 55.5
counts/s summed, flat Poisson, one good-time interval a day -- is searched with the default
timescales (64 ms to 16.384 s) and background window (20 s) at the default false-alarm rate
(one a day) and at looser ones (one an hour, a minute, ten seconds), each stating ``E[false
candidates] <= far * searched`` (a Bonferroni bound).  Printed: the stated rate, the
measured rate with its Poisson 68 % interval, their ratio, the trials per second, the
threshold in sigma and the run time per day of data; then the false candidates of the
loosest rates by timescale beside the bound's share of each timescale.  Event times are
drawn directly (uniform in the day, Poisson in number), a day at a time, so memory stays
that of one day (~5 M events).

    python benchmarks/bursts_far.py              # 2 days (~5 s on 2 shared cores)
    python benchmarks/bursts_far.py --days 100   # the saved run (~2 min): the rate at 1/day
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from rotmod.bursts.search import DEFAULT_TIMESCALES, search
from rotmod.events import EventList
from rotmod.testing import tiny_instrument

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results" / "bursts_far.txt"

SEED = 20260601
DAY = 86400.0
N_DET = 37
RATE = 1.5  # counts/s per detector
FARS = [("1/day", 1.0 / DAY), ("1/hour", 1.0 / 3600.0), ("1/min", 1.0 / 60.0),
        ("1/10s", 0.1)]


def simulate_day(rng: np.random.Generator, instrument, day: int) -> EventList:
    """One day of flat Poisson background, all detectors (times drawn directly)."""
    t0 = day * DAY
    n = rng.poisson(N_DET * RATE * DAY)
    t = np.sort(rng.uniform(t0, t0 + DAY, n))
    det = rng.integers(0, N_DET, n)
    energy = np.full(n, 100.0, dtype=np.float32)
    return EventList(t, det, energy, instrument, [[t0, t0 + DAY]])


def poisson_interval(n: int) -> tuple[float, float]:
    """Central 68.27 % (Garwood) interval of a Poisson mean given ``n`` counts."""
    lo = 0.0 if n == 0 else chi2.ppf(0.158655, 2 * n) / 2.0
    hi = chi2.ppf(0.841345, 2 * n + 2) / 2.0
    return float(lo), float(hi)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--days", type=int, default=2, help="days of data (default 2)")
    parser.add_argument("--no-save", action="store_true",
                        help=f"do not write {RESULTS.relative_to(ROOT)}")
    args = parser.parse_args(argv)
    instrument = tiny_instrument(rings=3)  # 37 detectors
    assert len(instrument.detectors) == N_DET
    counts = {name: 0 for name, _ in FARS}
    by_scale = {name: np.zeros(len(DEFAULT_TIMESCALES), dtype=int) for name, _ in FARS}
    searched = {name: 0.0 for name, _ in FARS}
    seconds = {name: 0.0 for name, _ in FARS}
    info: dict[str, tuple[float, float]] = {}
    sim_time = 0.0
    n_events = 0
    for day in range(args.days):
        rng = np.random.default_rng([SEED, day])
        t = time.perf_counter()
        events = simulate_day(rng, instrument, day)
        sim_time += time.perf_counter() - t
        n_events += len(events)
        for name, far in FARS:
            t = time.perf_counter()
            res = search(events, far=far)
            seconds[name] += time.perf_counter() - t
            counts[name] += len(res.candidates)
            searched[name] += res.searched
            info[name] = (res.trials_per_second, res.threshold_sigma)
            for c in res.candidates:
                by_scale[name][int(np.argmin(np.abs(np.array(res.timescales) - c.timescale)))] += 1
        del events
        print(f"day {day + 1}/{args.days} done", file=sys.stderr)

    lines = [
        "Burst trigger false-alarm rate: python benchmarks/bursts_far.py "
        + " ".join(sys.argv[1:] if argv is None else argv),
        f"{args.days} days of flat Poisson background, {N_DET} detectors x {RATE} counts/s = "
        f"{N_DET * RATE:g} counts/s summed ({n_events} events); default timescales "
        f"{DEFAULT_TIMESCALES[0]:g}-{DEFAULT_TIMESCALES[-1]:g} s (x2), background window 20 s, "
        "gap max(timescale, 4 s), one band",
        f"numpy {np.__version__}, Python {platform.python_version()}, "
        f"simulation {sim_time / args.days:.2f} s/day",
        "",
        f"{'stated far':>10} {'far (1/s)':>10} {'expected<=':>10} {'found':>6} "
        f"{'measured (1/s)':>14} {'68% interval (1/s)':>23} {'measured/far':>12} "
        f"{'trials/s':>8} {'thr sigma':>9} {'s/day':>6}",
    ]
    for name, far in FARS:
        n = counts[name]
        span = searched[name]
        lo, hi = poisson_interval(n)
        trials, sigma = info[name]
        lines.append(
            f"{name:>10} {far:10.3g} {far * span:10.1f} {n:6d} {n / span:14.3g} "
            f"{f'[{lo / span:.3g}, {hi / span:.3g}]':>23} {n / span / far:12.3f} "
            f"{trials:8.2f} {sigma:9.3f} {seconds[name] / args.days:6.2f}"
        )
    lines += ["", "False candidates by timescale (the most significant window of each) beside "
              "the Bonferroni share of the stated count (trials of a timescale / all trials):"]
    share = (1.0 / np.asarray(DEFAULT_TIMESCALES)) / np.sum(1.0 / np.asarray(DEFAULT_TIMESCALES))
    header = f"{'timescale (s)':>13}" + "".join(
        f" {name + ' found':>13} {name + ' bound':>13}" for name, _ in FARS[2:])
    lines.append(header)
    for j, d in enumerate(DEFAULT_TIMESCALES):
        row = f"{d:13.3f}"
        for name, far in FARS[2:]:
            row += f" {by_scale[name][j]:13d} {share[j] * far * searched[name]:13.1f}"
        lines.append(row)
    text = "\n".join(lines)
    print(text)
    if not args.no_save:
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        RESULTS.write_text(text + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
