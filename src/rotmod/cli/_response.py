"""``rotmod response``: build a response and store it as a zarr store."""

from __future__ import annotations

import argparse
from typing import Any

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
)


def register(sub: Any) -> None:
    p = sub.add_parser(
        "response",
        help="build and store a response (zarr); on Dask with --scheduler",
        description="Compute the response P[d, t, n] of an instrument on a square sky grid "
        "with a profile model and store it as a chunked, compressed zarr store with its "
        "provenance. The write is atomic and resumable: rerunning after an interruption "
        "computes only the missing chunks.",
        epilog="example: rotmod response -i paper --model exact --fov 14 --pixel 0.2 "
        "--bins 560 -o response.zarr --progress",
    )
    add_instrument(p)
    add_energy(p)
    p.add_argument("-m", "--model", default=None, metavar="NAME",
                   help="profile model (standard, advanced, advanced-approx, advanced-g0, "
                   "exact; default exact)")
    p.add_argument("--fov", type=quantity("deg"), default=14.0, metavar="DEG",
                   help="side of the square field (deg; default 14, the paper's)")
    p.add_argument("--pixel", type=quantity("deg"), default=0.2, metavar="DEG",
                   help="pixel size (deg; default 0.2 = 12 arcmin, the paper's)")
    p.add_argument("--center", type=str, default="0,0", metavar="X,Y",
                   help="tangent-plane centre of the field (deg; default 0,0)")
    p.add_argument("-n", "--bins", type=count(1), default=560, metavar="N",
                   help="mask-angle bins per rotation (default 560, the paper's)")
    p.add_argument("--bin-mode", choices=("center", "average"), default="center",
                   help="response of a bin: value at its centre or its mean (default center)")
    p.add_argument("--dtype", choices=("float32", "float64"), default="float32",
                   help="storage type (default float32)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler address (e.g. tcp://host:8786); default local threads")
    add_progress(p)
    add_output(p, help="response store (a .zarr directory)")
    p.set_defaults(func=run)


def parse_center(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise UserError(f"--center: must be X,Y in degrees, got {text!r}") from None
    return x, y


def run(args: argparse.Namespace) -> int:
    from rotmod.profiles import DEFAULT_MODEL, MODELS
    from rotmod.response.stored import write_response

    args.model = args.model or DEFAULT_MODEL
    from rotmod.response import TimeBinning
    from rotmod.sky import SkyGrid

    out = check_output(args.output, args.overwrite)
    if args.model not in MODELS:
        raise UserError(f"--model: must be one of {', '.join(sorted(MODELS))}, got "
                        f"{args.model!r}")
    if args.bins < 1:
        raise UserError(f"--bins: must be >= 1, got {args.bins}")
    cfg = load_config(args)
    inst = cfg.to_instrument()
    energy = energy_of(args, cfg)
    grid = SkyGrid.square(args.fov, args.pixel, parse_center(args.center))
    bins = TimeBinning(args.bins, args.bin_mode)
    say(f"rotmod: response {args.model}: {len(inst.detectors)} detector(s) x {args.bins} bins x "
        f"{grid.size} pixels ({grid.shape[1]}x{grid.shape[0]}), {energy:g} keV"
        f"{', scheduler ' + args.scheduler if args.scheduler else ''}")
    stored = write_response(
        out, inst, grid, bins, args.model, energy, dtype=args.dtype, overwrite=args.overwrite,
        scheduler=args.scheduler, progress=progress_wanted(args),
    )
    say(f"rotmod: wrote {out} (shape {stored.n_det} x {stored.n_time} x {stored.n_sky})")
    return 0
