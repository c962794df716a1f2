"""``rotmod simulate``: a Monte Carlo observation written as a FITS event list."""

from __future__ import annotations

import argparse
import contextlib
import sys
from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import SkyCoord

from rotmod.cli._common import (
    UserError,
    add_attitude,
    add_energy,
    add_instrument,
    add_output,
    add_progress,
    attitude_of,
    check_files,
    count,
    energy_of,
    heartbeat,
    intervals_of,
    load_config,
    parse_radec,
    progress_wanted,
    quantity,
    say,
    source_arg,
    to_number,
    warn_if_mirror_degenerate,
)
from rotmod.io import write_events
from rotmod.montecarlo import simulate_drift, simulate_observation
from rotmod.progress import Progress
from rotmod.sky import AttitudeTable, PointSources

#: Source rate when a --source or --sky-source gives none (photons/s per detector, no mask).
DEFAULT_RATE = 10.0


def register(sub: Any) -> None:
    p = sub.add_parser(
        "simulate",
        help="Monte Carlo observation -> FITS event list",
        description="Simulate a time-tagged observation of point sources through the rotating "
        "3-D mask (analog photon transport) and write the events as a FITS event list. "
        "Sources are given in the instrument frame (--source) or on the sky (--sky-source, "
        "with the attitude: a fixed --pointing/--roll, or an --attitude table for a drifting "
        "observation over [0, --exposure] s). The event file records the pointing (the "
        "attitude of the middle constant-attitude piece for a drift); an attitude table is not "
        "copied into it: "
        "give the same --attitude (and --max-step) to rotmod response.",
        epilog="examples: rotmod simulate -i prototype --source 6,30,50 --exposure 600 "
        "--seed 1 -o events.fits;  rotmod simulate -i prototype --pointing 83.6,22.0 --roll "
        "30 --sky-source 84.5,23.0,40 -t 600 -o crab.fits;  rotmod simulate -i prototype "
        "--attitude aspect.ecsv --sky-source 201.5,-59.2,30 -t 1200 -o drift.fits",
    )
    add_instrument(p)
    add_energy(p)
    p.add_argument("-s", "--source", action="append", type=source_arg(with_rate=True),
                   default=[], metavar="THETA,PHI[,RATE]",
                   help="source zenith, azimuth (deg, instrument frame) and rate (photons/s "
                   f"on each detector with no mask; default {DEFAULT_RATE:g}); repeatable")
    p.add_argument("--sky-source", action="append", default=[], metavar="RA,DEC[,RATE]",
                   help="source on the sky (ICRS, deg) and rate (as --source); repeatable; "
                   "needs --pointing or --attitude")
    add_attitude(p)
    p.add_argument("-t", "--exposure", type=quantity("s"), required=True, metavar="SECONDS",
                   help="observation length (s)")
    p.add_argument("--background", type=quantity("1/s"), default=0.0, metavar="RATE",
                   help="flat background rate per detector (1/s; default 0)")
    p.add_argument("--seed", type=count(0), default=None, help="random seed (default: fresh)")
    add_progress(p)
    add_output(p, help="event list (FITS)")
    p.set_defaults(func=run)


def parse_sky_source(text: str) -> tuple[float, float, float]:
    """``RA,DEC[,RATE]`` (deg, deg, photons/s) of ``--sky-source``."""
    parts = [x.strip() for x in text.split(",")]
    if len(parts) not in (2, 3):
        raise UserError(f"--sky-source: must be RA,DEC[,RATE] (deg, deg, photons/s), got "
                        f"{text!r}")
    ra, dec = parse_radec(",".join(parts[:2]), "--sky-source")
    try:
        rate = to_number(parts[2], "1/s") if len(parts) == 3 else DEFAULT_RATE
    except argparse.ArgumentTypeError as exc:
        raise UserError(f"--sky-source: RATE: {exc}, in {text!r}") from None
    if rate < 0:
        raise UserError(f"--sky-source: rate must be >= 0 photons/s, got {rate:g}")
    return ra, dec, rate


def run(args: argparse.Namespace) -> int:
    out = check_files({"--instrument": args.instrument, "--attitude": args.attitude},
                      {"--output": args.output}, args.overwrite)["--output"]
    if not np.isfinite(args.exposure) or args.exposure <= 0:
        raise UserError(f"--exposure: must be > 0 s, got {args.exposure:g} s")
    if not np.isfinite(args.background) or args.background < 0:
        raise UserError(f"--background: must be >= 0 /s, got {args.background:g}")
    sky = [parse_sky_source(t) for t in args.sky_source]
    if not sky and not args.source:
        raise UserError("--source or --sky-source: give at least one source")
    att = attitude_of(args)
    if sky and att is None:
        raise UserError("--sky-source: needs the attitude that places the instrument on the "
                        "sky: --pointing RA,DEC [--roll DEG] or --attitude FILE")
    if isinstance(att, AttitudeTable) and args.source:
        raise UserError("--source: with --attitude the instrument frame moves on the sky; "
                        "give the sources by --sky-source RA,DEC[,RATE]")
    cfg = load_config(args)
    inst = cfg.to_instrument()
    warn_if_mirror_degenerate(inst, "rotmod simulate")
    energy = energy_of(args, cfg)
    meta = {"object": "rotmod simulate", "instrume": cfg.name or "custom"}
    # One SeedSequence for the simulation and the file: a fresh seed is recorded too.
    seed = np.random.SeedSequence(args.seed)
    want = progress_wanted(args)
    if isinstance(att, AttitudeTable):
        intervals = intervals_of(att, 0.0, args.exposure, args.max_step)
        coords = SkyCoord([s[0] for s in sky] * u.deg, [s[1] for s in sky] * u.deg)
        # The pieces are few and the first one compiles the kernels: log lines, not a bar.
        with heartbeat(args, "MC observation", len(intervals), "piece") as bar:
            events = simulate_drift(
                inst, coords, intervals, rate=[s[2] for s in sky], energy=energy,
                background=args.background, seed=seed, meta=meta,
                progress=None if bar is None else bar.update_to,
            )
        where = f", {len(intervals)} attitude pieces"
    else:
        src = np.array([s if len(s) == 3 else (*s, DEFAULT_RATE) for s in args.source],
                       dtype=float).reshape(-1, 3)  # deg, deg, 1/s
        if sky:  # on the sky: where the fixed attitude sees them (PointSources.from_sky)
            on_sky = PointSources.from_sky(
                SkyCoord([s[0] for s in sky] * u.deg, [s[1] for s in sky] * u.deg), att)
            src = np.vstack([src, np.column_stack([
                np.degrees(on_sky.theta.to_value(u.rad)), np.degrees(on_sky.phi.to_value(u.rad)),
                [s[2] for s in sky]])])
        theta, phi, rate = src.T
        sources = PointSources(theta, phi, rate, energy)  # deg
        with (Progress(None, "MC observation", "ms", tty=sys.stderr.isatty()) if want
              else contextlib.nullcontext()) as bar:
            events = simulate_observation(
                inst, sources, t_stop=args.exposure, background=args.background,
                seed=seed, progress=None if bar is None else bar.update_to, meta=meta,
                attitude=att,
            )
        where = "" if att is None else f", pointing RA {att.ra:g} Dec {att.dec:g} deg"
    write_events(events, out, overwrite=args.overwrite, seed=seed, command=args.command_line)
    say(f"rotmod: wrote {out} ({len(events)} events, {len(inst.detectors)} detector(s), "
        f"{args.exposure:g} s, {energy:g} keV{where})")
    return 0
