"""``rotmod response``: build a response and store it as a zarr store.

``--operator matrix`` (default) computes and stores every value ``P[d, t, n]`` of a profile
model; ``--operator radon`` stores the table of a :class:`~rotmod.response.RadonResponse`
(the exact model within ``--tolerance``), which is what makes wide fields storable:
megabytes instead of ``n_det n_time n_sky`` values.  ``rotmod reconstruct`` opens either.
"""

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
    registered,
    say,
)
from rotmod.profiles import DEFAULT_MODEL, MODELS
from rotmod.response import RadonResponse, TimeBinning, save_response, write_response
from rotmod.sky import SkyGrid


def register(sub: Any) -> None:
    p = sub.add_parser(
        "response",
        help="build and store a response (zarr); on Dask with --scheduler",
        description="Compute the response of an instrument on a square sky grid and store "
        "it as a chunked, compressed, checksummed zarr store with its provenance. "
        "--operator matrix (default) stores every value P[d, t, n] of a profile model (atomic "
        "and resumable: rerunning after an interruption computes only the missing chunks); "
        "--operator radon stores the table of the Radon-factorised exact model, accurate to "
        "--tolerance, small enough for wide fields (rule: use radon when n_det x n_time x "
        "n_sky values do not fit in memory, or to image fast; matrix for small grids reused "
        "many times or other models).",
        epilog="examples: rotmod response -i paper --model exact --fov 14 --pixel 0.2 "
        "--bins 560 -o response.zarr --progress;  rotmod response -i prototype --operator "
        "radon --fov 20 --pixel 0.1 --tangent 48,30 -o wide.zarr",
    )
    add_instrument(p)
    add_energy(p)
    p.add_argument("--operator", choices=("matrix", "radon"), default="matrix",
                   help="what to store: every value of P (matrix, default) or the Radon "
                   "factorisation's table (radon; the exact model)")
    p.add_argument("-m", "--model", default=None, metavar="NAME",
                   help=f"profile model ({', '.join(MODELS.names())}; default "
                   f"{DEFAULT_MODEL}; radon is always exact)")
    p.add_argument("--tolerance", type=float, default=1e-4, metavar="DP",
                   help="radon: largest error of any profile value (default 1e-4)")
    p.add_argument("--fov", type=quantity("deg"), default=14.0, metavar="DEG",
                   help="side of the square field (deg; default 14, the paper's)")
    p.add_argument("--pixel", type=quantity("deg"), default=0.2, metavar="DEG",
                   help="pixel size (deg; default 0.2 = 12 arcmin, the paper's)")
    p.add_argument("--center", type=str, default="0,0", metavar="X,Y",
                   help="tangent-plane centre of the field (deg; default 0,0)")
    p.add_argument("--tangent", type=str, default="0,0", metavar="THETA,PHI",
                   help="instrument direction where the projection plane touches the sky "
                   "(deg; default 0,0, the axis): a field centred far off axis keeps square "
                   "pixels")
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


def parse_pair(text: str, option: str = "--center", names: str = "X,Y") -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise UserError(f"{option}: must be {names} in degrees, got {text!r}") from None
    return x, y


def run(args: argparse.Namespace) -> int:
    args.model = registered(MODELS, args.model or DEFAULT_MODEL, "--model")
    out = check_output(args.output, args.overwrite)
    if args.operator == "radon" and args.model != "exact":
        raise UserError(f"--model: --operator radon factorises the exact model, got "
                        f"{args.model!r}")
    if args.bins < 1:
        raise UserError(f"--bins: must be >= 1, got {args.bins}")
    cfg = load_config(args)
    inst = cfg.to_instrument()
    energy = energy_of(args, cfg)
    grid = SkyGrid.square(args.fov, args.pixel, parse_pair(args.center),
                          tangent=parse_pair(args.tangent, "--tangent", "THETA,PHI"))
    bins = TimeBinning(args.bins, args.bin_mode)
    kind = "radon (exact)" if args.operator == "radon" else args.model
    say(f"rotmod: response {kind}: {len(inst.detectors)} detector(s) x {args.bins} bins x "
        f"{grid.size} pixels ({grid.shape[1]}x{grid.shape[0]}), {energy:g} keV"
        f"{', scheduler ' + args.scheduler if args.scheduler else ''}")
    if args.operator == "radon":
        radon = RadonResponse(inst, grid, bins, energy, tolerance=args.tolerance,
                              dtype=args.dtype)
        save_response(out, radon, overwrite=args.overwrite)
        j, kr = radon.table.shape
        say(f"rotmod: wrote {out} (Radon table {j} x {kr}, tolerance {args.tolerance:g})")
        return 0
    stored = write_response(
        out, inst, grid, bins, args.model, energy, dtype=args.dtype, overwrite=args.overwrite,
        scheduler=args.scheduler, progress=progress_wanted(args),
    )
    say(f"rotmod: wrote {out} (shape {stored.n_det} x {stored.n_time} x {stored.n_sky})")
    return 0
