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
    BINS_HELP,
    DEFAULT_BINS,
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
    registered,
    say,
    warn_if_mirror_degenerate,
)
from rotmod.profiles import DEFAULT_MODEL, MODELS
from rotmod.response import RadonResponse, TimeBinning, save_response, write_response
from rotmod.response.drift import drift_response
from rotmod.response.radon import DEFAULT_TOLERANCE
from rotmod.sky import Attitude, AttitudeTable, CelestialGrid, HealpixGrid, SkyGeometry, SkyGrid


def register(sub: Any) -> None:
    p = sub.add_parser(
        "response",
        help="build and store a response (zarr); on Dask with --scheduler",
        description="Compute the response of an instrument on a sky grid and store "
        "it as a chunked, compressed, checksummed zarr store with its provenance. "
        "--grid instrument (default) is a square field in the instrument frame; --grid "
        "celestial a TAN image on the sky (RA/Dec, north up) and --grid healpix the HEALPix "
        "pixels within --radius of a centre, both placed by the attitude: a fixed "
        "--pointing/--roll, or an --attitude table for a drifting observation (the response "
        "is then the exposure-weighted sum over its pieces of constant attitude, over "
        "[0, --exposure] s as in rotmod simulate). "
        "--operator matrix (default) stores every value P[d, t, n] of a profile model (atomic "
        "and resumable: rerunning after an interruption computes only the missing chunks); "
        "--operator radon stores the table of the Radon-factorised exact model, accurate to "
        "--tolerance, small enough for wide fields (rule: use radon when n_det x n_time x "
        "n_sky values do not fit in memory, or to image fast; matrix for small grids reused "
        "many times or other models).",
        epilog="examples: rotmod response -i prototype --model exact --fov 14 --pixel 0.5 "
        "-o response.zarr;  rotmod response -i prototype --operator radon --fov 20 --pixel "
        "0.1 --tangent 48,30 -o wide.zarr;  rotmod response -i prototype --grid celestial "
        "--attitude aspect.ecsv --exposure 1200 --fov 8 --pixel 0.5 -o sky.zarr;  rotmod "
        "response -i prototype --grid healpix --pointing 83.6,22.0 --nside 64 --radius 5 "
        "-o hpx.zarr",
    )
    add_instrument(p)
    add_energy(p)
    p.add_argument("--operator", choices=("matrix", "radon"), default="matrix",
                   help="what to store: every value of P (matrix, default) or the Radon "
                   "factorisation's table (radon; the exact model)")
    p.add_argument("-m", "--model", default=None, metavar="NAME",
                   help=f"profile model ({', '.join(MODELS.names())}; default "
                   f"{DEFAULT_MODEL}; radon is always exact)")
    p.add_argument("--tolerance", type=float, default=None, metavar="DP",
                   help="radon only: largest error of any profile value (default 1e-4; "
                   "refused with --operator matrix, which has no interpolation error)")
    add_grid_options(p)
    add_attitude(p)
    p.add_argument("-t", "--exposure", type=quantity("s"), default=None, metavar="SECONDS",
                   help="with --attitude: the observation runs over [0, SECONDS] (give rotmod "
                   "simulate's; default the table's last time)")
    p.add_argument("-n", "--bins", type=count(1), default=DEFAULT_BINS, metavar="N",
                   help=BINS_HELP)
    p.add_argument("--bin-mode", choices=("center", "average"), default="center",
                   help="response of a bin: value at its centre or its mean (default center)")
    p.add_argument("--dtype", choices=("float32", "float64"), default="float32",
                   help="storage type (default float32)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler address (e.g. tcp://host:8786); default local threads")
    add_progress(p)
    add_output(p, help="response store (a .zarr directory)")
    p.set_defaults(func=run)


def add_grid_options(p: argparse.ArgumentParser) -> None:
    """The sky grid's options (``--grid``, ``--fov``, ``--pixel``, ...; :func:`make_grid`),
    shared with the commands that build a response on the fly (``rotmod detect``)."""
    p.add_argument("--grid", choices=("instrument", "celestial", "healpix"),
                   default="instrument",
                   help="sky grid: a square field in the instrument frame (default), a TAN "
                   "image on the celestial sphere, or HEALPix pixels (both need the attitude)")
    p.add_argument("--fov", type=quantity("deg"), default=14.0, metavar="DEG",
                   help="instrument/celestial: side of the square field (deg; default 14, "
                   "the paper's)")
    p.add_argument("--pixel", type=quantity("deg"), default=0.2, metavar="DEG",
                   help="instrument/celestial: pixel size (deg; default 0.2 = 12 arcmin, the "
                   "paper's)")
    p.add_argument("--center", type=str, default="0,0", metavar="X,Y",
                   help="instrument: tangent-plane centre of the field (deg; default 0,0)")
    p.add_argument("--tangent", type=str, default="0,0", metavar="THETA,PHI",
                   help="instrument: direction where the projection plane touches the sky "
                   "(deg; default 0,0, the axis): a field centred far off axis keeps square "
                   "pixels")
    p.add_argument("--sky-center", default=None, metavar="RA,DEC",
                   help="celestial/healpix: centre of the image or cone (ICRS, deg; default "
                   "the pointing, or the attitude table's at mid-observation)")
    p.add_argument("--nside", type=count(1), default=64, metavar="N",
                   help="healpix: resolution, a power of 2 (pixels ~58.6/N deg; default 64)")
    p.add_argument("--radius", type=quantity("deg"), default=7.0, metavar="DEG",
                   help="healpix: radius of the cone of pixels (deg; default 7)")


def parse_pair(text: str, option: str = "--center", names: str = "X,Y") -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise UserError(f"{option}: must be {names} in degrees, got {text!r}") from None
    return x, y


def make_grid(args: argparse.Namespace, attitude: Attitude | None) -> SkyGeometry:
    """The ``--grid`` asked for; ``attitude`` places a celestial or HEALPix grid."""
    if args.grid == "instrument":
        return SkyGrid.square(args.fov, args.pixel, parse_pair(args.center),
                              tangent=parse_pair(args.tangent, "--tangent", "THETA,PHI"))
    if attitude is None:
        raise UserError(f"--grid {args.grid}: needs the attitude that places it on the sky: "
                        "--pointing RA,DEC [--roll DEG] or --attitude FILE")
    ra, dec = (parse_radec(args.sky_center, "--sky-center") if args.sky_center is not None
               else (attitude.ra, attitude.dec))
    if args.grid == "healpix":
        return HealpixGrid(args.nside, ra, dec, args.radius, attitude)
    if not args.fov > 0 or not args.pixel > 0:
        raise UserError(f"--fov and --pixel: must be > 0 deg, got {args.fov:g} and "
                        f"{args.pixel:g}")
    n = max(1, round(args.fov / args.pixel))
    return CelestialGrid((n, n), args.pixel, ra, dec, attitude)


def _shape(args: argparse.Namespace, grid: SkyGeometry) -> str:
    """The grid in words: ``celestial grid 12x12`` or ``healpix grid nside 128``."""
    if isinstance(grid, HealpixGrid):
        return f"healpix grid nside {grid.nside} within {grid.radius:g} deg"
    return f"{args.grid} grid {grid.shape[1]}x{grid.shape[0]}"


def run(args: argparse.Namespace) -> int:
    args.model = registered(MODELS, args.model or DEFAULT_MODEL, "--model")
    out = check_files({"--instrument": args.instrument, "--attitude": args.attitude},
                      {"--output": args.output}, args.overwrite,
                      stores=("--output",))["--output"]
    if args.operator == "radon" and args.model != "exact":
        raise UserError(f"--model: --operator radon factorises the exact model, got "
                        f"{args.model!r}")
    if args.bins < 1:
        raise UserError(f"--bins: must be >= 1, got {args.bins}")
    if args.tolerance is not None and args.operator != "radon":
        raise UserError(f"--tolerance: only with --operator radon (the matrix operator stores "
                        f"the model's values, with no interpolation error to bound), got "
                        f"--tolerance {args.tolerance:g}")
    tolerance = DEFAULT_TOLERANCE if args.tolerance is None else args.tolerance
    att = attitude_of(args)
    if isinstance(att, AttitudeTable) and args.grid == "instrument":
        raise UserError("--attitude: a drifting observation is imaged on the sky; add --grid "
                        "celestial or --grid healpix (the instrument frame moves on the sky)")
    if args.exposure is not None and not isinstance(att, AttitudeTable):
        raise UserError("--exposure: only with --attitude (the time span of the drift)")
    intervals = None
    if isinstance(att, AttitudeTable):
        t_stop = float(att.time[-1]) if args.exposure is None else args.exposure
        if not t_stop > 0:
            raise UserError(f"--exposure: must be > 0 s, got {t_stop:g} s (an attitude table "
                            "ending at time 0 needs --exposure)")
        intervals = intervals_of(att, 0.0, t_stop, args.max_step)
        att = att.at(0.5 * t_stop)  # the image's nominal attitude (each piece uses its own)
    cfg = load_config(args)
    inst = cfg.to_instrument()
    warn_if_mirror_degenerate(inst, "rotmod response")
    energy = energy_of(args, cfg)
    grid = make_grid(args, att)
    bins = TimeBinning(args.bins, args.bin_mode)
    kind = "radon (exact)" if args.operator == "radon" else args.model
    drift = f", {len(intervals)} attitude pieces" if intervals else ""
    say(f"rotmod: response {kind}: {len(inst.detectors)} detector(s) x {args.bins} bins x "
        f"{grid.size} pixels ({_shape(args, grid)}), "
        f"{energy:g} keV{drift}{', scheduler ' + args.scheduler if args.scheduler else ''}")
    if intervals is not None:
        with heartbeat(args, "drift response"):  # drift_response reports no steps
            op = drift_response(inst, grid, bins, intervals, args.model, energy,
                                dtype=args.dtype, operator=args.operator,
                                tolerance=args.tolerance)  # None: the default
        stored = save_response(out, op, overwrite=args.overwrite)
        say(f"rotmod: wrote {out} (shape {stored.n_det} x {stored.n_time} x {stored.n_sky}, "
            f"exposure-weighted over {len(intervals)} attitude pieces)")
        return 0
    if args.operator == "radon":
        with heartbeat(args, "Radon table"):
            radon = RadonResponse(inst, grid, bins, energy, tolerance=tolerance,
                                  dtype=args.dtype)
        save_response(out, radon, overwrite=args.overwrite)
        j, kr = radon.table.shape
        say(f"rotmod: wrote {out} (Radon table {j} x {kr}, tolerance {tolerance:g})")
        return 0
    stored = write_response(
        out, inst, grid, bins, args.model, energy, dtype=args.dtype, overwrite=args.overwrite,
        scheduler=args.scheduler, progress=progress_wanted(args),
    )
    say(f"rotmod: wrote {out} (shape {stored.n_det} x {stored.n_time} x {stored.n_sky})")
    return 0
