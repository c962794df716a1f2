"""``rotmod burst``: bursts in an event list -> positions, regions, durations, summaries."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import Any

import astropy.units as u
import numpy as np
from astropy.table import Table

from rotmod.bursts import Burst, analyse_burst, search
from rotmod.cli._common import (
    UserError,
    add_attitude,
    add_energy,
    add_output,
    add_progress,
    check_covers,
    check_files,
    energy_of,
    progress_wanted,
    quantity,
    registered,
    save_figure,
    say,
    use_agg,
)
from rotmod.cli._sources import attitude
from rotmod.errors import ParameterError
from rotmod.events import EventList
from rotmod.io import read
from rotmod.io.atomic import write_text
from rotmod.io.config import load_instrument_config
from rotmod.io.regions import write_probability_map
from rotmod.io.tables import write_product_table
from rotmod.profiles import DEFAULT_MODEL, MODELS
from rotmod.sky import AttitudeTable


def register(sub: Any) -> None:
    p = sub.add_parser(
        "burst",
        help="find, localise and measure bursts in an event list -> summaries, maps",
        description="Search the detector-summed rates for bursts (several timescales, a "
        "stated false-alarm rate), then for each candidate fit the background before and "
        "after it, find its light curve (Bayesian blocks), measure T90/T50, net counts, "
        "peak rate, fluence and peak flux, and localise it with the time-tagged likelihood "
        "(light curve in the model): a score map of the visible sky, exact refits of its peaks, "
        "the 68 %% and 90 %% regions. Writes per burst OUT_N.fits (the burst's row), "
        "OUT_N_lc.fits (its light-curve blocks), OUT_N_prob.fits (HEALPix probability "
        "map), OUT_N.txt (a GCN-style summary, also printed) and OUT_N.png (light curve "
        "with the T90 interval, the TS map of the sky and the region's contours).",
        epilog="examples: rotmod burst events.fits -i survey.toml -e 300 -o grb;  "
        "rotmod burst events.fits -e 300 --far 1/3600 --systematic 0.5 -o out/burst",
    )
    p.add_argument("data", metavar="EVENTS", help="event list (FITS) with its pointing")
    p.add_argument("-i", "--instrument", default=None, metavar="FILE|PRESET",
                   help="instrument description or preset; default the event file's")
    add_energy(p)
    p.add_argument("-m", "--model", default=None, metavar="NAME",
                   help=f"profile model ({', '.join(MODELS.names())}; default {DEFAULT_MODEL})")
    p.add_argument("--far", default="1/86400", metavar="RATE",
                   help="false-alarm rate of the search (1/s; a fraction like 1/86400 is "
                   "accepted; default one per day)")
    p.add_argument("--radius", type=float, default=80.0, metavar="DEG",
                   help="searched cone around the pointing (deg, < 90; default 80)")
    p.add_argument("--systematic", type=quantity("deg"), default=0.0, metavar="DEG",
                   help="systematic position error per axis added to the regions (deg)")
    p.add_argument("--interval", default=None, metavar="T0,T1",
                   help="analyse this interval (s) instead of searching")
    add_output(p, help="prefix of the output files (OUT_1.fits, OUT_1_prob.fits, ...)")
    add_progress(p)
    add_attitude(p)
    p.set_defaults(func=run)


def _rate(text: str) -> float:
    try:
        if "/" in text:
            num, den = text.split("/", 1)
            value = float(num) / float(den)
        else:
            value = float(text)
    except (ValueError, ZeroDivisionError):
        raise UserError(f"--far: must be a rate in 1/s (e.g. 1/86400), got {text!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise UserError(f"--far: must be > 0 per second, got {text!r}")
    return value


def _interval(text: str) -> tuple[float, float]:
    """``--interval T0,T1``: two finite times (s) with ``T1 > T0``."""
    try:
        t0, t1 = (float(x) for x in text.split(","))
    except ValueError:
        raise UserError(f"--interval: must be T0,T1 (s), got {text!r}") from None
    if not (np.isfinite(t0) and np.isfinite(t1) and t1 > t0):
        raise UserError(f"--interval: must be two finite times T0,T1 (s) with T1 > T0, got "
                        f"{text!r}")
    return t0, t1


def _plot(burst: Burst, path: Any) -> None:
    use_agg()
    import matplotlib.pyplot as plt

    lc = burst.light_curve
    fig, (ax, bx, cx) = plt.subplots(1, 3, figsize=(14, 3.8), layout="constrained")
    ax.stairs(lc.net_rate, lc.edges, color="k", label="net rate (Bayesian blocks)")
    d = burst.durations
    ax.axvspan(d.t90_start, d.t90_start + d.t90, color="C1", alpha=0.25,
               label=f"T90 = {d.t90:.2f} +/- {d.t90_err:.2f} s")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("counts/s (all detectors)")
    ax.legend(fontsize=7)
    score = burst.position.score
    th, ph = score.grid.directions()
    sc = bx.scatter(np.degrees(ph.value), np.degrees(th.value), c=score.score, s=1,
                    cmap="viridis", rasterized=True)
    bx.plot(burst.position.phi, burst.position.theta, "r+", ms=12, label="best")
    bx.set_xlabel("azimuth phi (deg)")
    bx.set_ylabel("off-axis theta (deg)")
    bx.set_title("score of the visible sky (search map)", fontsize=9)
    fig.colorbar(sc, ax=bx, label="U / sqrt(I)")
    bx.legend(fontsize=7)
    # The region on the sky: its 68 % and 90 % contours around the best position.
    region = burst.position.region
    best = burst.position.position.icrs
    for level, style in ((0.68, "-"), (0.9, "--")):
        for k, ring in enumerate(region.contour(level)):
            cx.plot(ring.ra.deg, ring.dec.deg, "k" + style,
                    label=f"{level:.0%} region" if k == 0 else None)
    cx.plot(best.ra.deg, best.dec.deg, "r+", ms=12, label="best")
    cx.set_xlabel("RA (deg)")
    cx.set_ylabel("Dec (deg)")
    cx.invert_xaxis()
    cx.set_title(f"region (r90 {region.radius(0.9):.2f} deg)", fontsize=9)
    cx.legend(fontsize=7, loc="lower right")
    save_figure(fig, path)


def _blocks_table(burst: Burst) -> Table:
    lc = burst.light_curve
    t = Table()
    t["time_min"] = lc.edges[:-1] * u.s
    t["time_max"] = lc.edges[1:] * u.s
    t["counts"] = lc.counts
    t["background"] = lc.background
    t["net_rate"] = lc.net_rate * u.Unit("1/s")
    return t


def run(args: argparse.Namespace) -> int:
    files = check_files({"EVENTS": args.data, "--instrument": args.instrument,
                         "--attitude": args.attitude}, {}, args.overwrite)
    path = files["EVENTS"]
    far = _rate(args.far)
    if not 0 < args.radius < 90:
        raise UserError(f"--radius: must be in (0, 90) deg, got {args.radius:g}")
    if not args.systematic >= 0:
        raise UserError(f"--systematic: must be >= 0 deg, got {args.systematic:g}")
    if not (np.isfinite(args.max_step) and args.max_step > 0):
        raise UserError(f"--max-step: must be > 0 s, got {args.max_step:g} s")
    model = registered(MODELS, args.model or DEFAULT_MODEL, "--model")
    given = None if args.interval is None else _interval(args.interval)
    events = read(path)
    if not isinstance(events, EventList):
        raise UserError(f"EVENTS {str(path)!r}: must be an event list, got a file of "
                        f"{type(events).__name__}")
    if args.instrument is not None:
        cfg = load_instrument_config(args.instrument)
        energy = energy_of(args, cfg)
        try:
            events = dataclasses.replace(events, instrument=cfg.to_instrument())
        except ParameterError as exc:
            raise UserError(f"--instrument: does not fit EVENTS {str(path)!r}: {exc}") from None
    elif args.energy is None:
        raise UserError("--energy: give the photon energy of the response (keV), or -i with "
                        "the instrument file")
    else:
        energy = energy_of(args, None)
    att = attitude(args, events)
    if att is None:
        raise UserError("--pointing/--attitude: the event file records no pointing, and a "
                        "burst is placed on the sky through it")
    if isinstance(att, AttitudeTable):
        check_covers(att, events.t_start, events.t_stop, "give the table of these events")
    if given is not None:
        if given[1] <= events.t_start or given[0] >= events.t_stop:
            raise UserError(f"--interval: {given[0]:g},{given[1]:g} s lies outside the events "
                            f"({events.t_start:g} .. {events.t_stop:g} s)")
        intervals: list[Any] = [given]
    else:
        found = search(events, far=far)
        say(f"rotmod: burst: searched {found.searched:.0f} s at {far:.3g}/s false alarms "
            f"(threshold {found.threshold_sigma:.2f} sigma): {len(found.candidates)} "
            "candidate(s)")
        intervals = list(found.candidates)
    # The names come from the candidates found: checked now, before any burst's work.
    exts = (".fits", "_lc.fits", "_prob.fits", ".txt", ".png")
    files = files.more({f"-o {args.output} (burst {k}, {ext})": f"{args.output}_{k}{ext}"
                        for k in range(1, len(intervals) + 1) for ext in exts},
                       plots=tuple(f"-o {args.output} (burst {k}, .png)"
                                   for k in range(1, len(intervals) + 1)))
    paths = [{ext: files[f"-o {args.output} (burst {k}, {ext})"] for ext in exts}
             for k in range(1, len(intervals) + 1)]
    cache: dict = {}
    for k, (interval, out) in enumerate(zip(intervals, paths, strict=True), 1):
        name = f"burst {k}"
        try:
            b = analyse_burst(events, interval, energy=energy, model=model, attitude=att,
                              max_step=args.max_step, radius=args.radius,
                              systematic=args.systematic, cache=cache,
                              progress=progress_wanted(args) or None)
        except ParameterError as exc:
            say(f"rotmod: {name}: not analysed: {exc}")
            continue
        text = b.summary(name)
        print(text)
        write_text(out[".txt"], text + "\n")
        write_product_table(b.to_table(), out[".fits"], extname="BURST",
                            overwrite=args.overwrite, command=sys.argv)
        write_product_table(_blocks_table(b), out["_lc.fits"], extname="LIGHTCURVE",
                            overwrite=args.overwrite, command=sys.argv)
        write_probability_map(b.position.probability_map(), out["_prob.fits"],
                              overwrite=args.overwrite, command=sys.argv)
        _plot(b, out[".png"])
        say(f"rotmod: {name}: wrote {out['.fits']}, {out['_prob.fits']}, {out['.txt']}, "
            f"{out['.png']}")
    return 0
