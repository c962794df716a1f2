"""``rotmod simulate``: a Monte Carlo observation written as a FITS event list."""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from rotmod.cli._common import (
    UserError,
    add_energy,
    add_instrument,
    add_output,
    add_progress,
    check_output,
    count,
    energy_of,
    load_config,
    progress_wanted,
    quantity,
    say,
    source_arg,
)
from rotmod.io import write_events
from rotmod.montecarlo import simulate_observation
from rotmod.sky import PointSources


def register(sub: Any) -> None:
    p = sub.add_parser(
        "simulate",
        help="Monte Carlo observation -> FITS event list",
        description="Simulate a time-tagged observation of point sources through the rotating "
        "3-D mask (analog photon transport) and write the events as a FITS event list.",
        epilog="example: rotmod simulate -i paper --source 6,30,50 --exposure 600 "
        "--seed 1 -o events.fits",
    )
    add_instrument(p)
    add_energy(p)
    p.add_argument("-s", "--source", action="append", type=source_arg(with_rate=True),
                   required=True, metavar="THETA,PHI[,RATE]",
                   help="source zenith, azimuth (deg) and rate (photons/s on each detector "
                   "with no mask; default 10); repeatable")
    p.add_argument("-t", "--exposure", type=quantity("s"), required=True, metavar="SECONDS",
                   help="observation length (s)")
    p.add_argument("--background", type=quantity("1/s"), default=0.0, metavar="RATE",
                   help="flat background rate per detector (1/s; default 0)")
    p.add_argument("--seed", type=count(0), default=None, help="random seed (default: fresh)")
    add_progress(p)
    add_output(p, help="event list (FITS)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = check_output(args.output, args.overwrite)
    if not np.isfinite(args.exposure) or args.exposure <= 0:
        raise UserError(f"--exposure: must be > 0 s, got {args.exposure:g} s")
    if not np.isfinite(args.background) or args.background < 0:
        raise UserError(f"--background: must be >= 0 /s, got {args.background:g}")
    cfg = load_config(args)
    inst = cfg.to_instrument()
    energy = energy_of(args, cfg)
    src = [s if len(s) == 3 else (*s, 10.0) for s in args.source]
    arr = np.array(src, dtype=float)
    sources = PointSources(arr[:, 0], arr[:, 1], arr[:, 2], energy)  # deg
    events = simulate_observation(
        inst, sources, t_stop=args.exposure, background=args.background, seed=args.seed,
        progress=progress_wanted(args),
        meta={"object": "rotmod simulate", "instrume": cfg.name or "custom"},
    )
    write_events(events, out, overwrite=args.overwrite)
    say(f"rotmod: wrote {out} ({len(events)} events, {len(inst.detectors)} detector(s), "
        f"{args.exposure:g} s, {energy:g} keV)")
    return 0
