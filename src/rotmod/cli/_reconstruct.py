"""``rotmod reconstruct``: folded profiles + a stored response -> FITS image and plot."""

from __future__ import annotations

import argparse
from typing import Any

import astropy.units as u
import numpy as np
from astropy.coordinates import SkyCoord

from rotmod.cli._common import (
    UserError,
    add_output,
    add_progress,
    check_files,
    count,
    describe_position,
    iteration_bar,
    parse_radec,
    progress_wanted,
    registered,
    save_figure,
    say,
    source_arg,
    use_agg,
    warn_if_mirror_degenerate,
)
from rotmod.io import read_folded
from rotmod.io.images import write_image
from rotmod.io.response_store import as_store_path, open_store
from rotmod.plotting.images import plot_image
from rotmod.reconstruction import ALGORITHMS, reconstruct
from rotmod.reconstruction.api import DEFAULT_METHOD
from rotmod.response import StoredResponse, open_response


def register(sub: Any) -> None:
    p = sub.add_parser(
        "reconstruct",
        help="folded profiles + response -> FITS image + plot",
        description="Reconstruct a sky image from folded count profiles (rotmod fold) with a "
        "stored response (rotmod response), and write it as FITS on the response's grid "
        "(instrument frame, celestial TAN WCS or HEALPix) and optionally a PNG plot. The "
        "response must have been computed for the data's instrument and number of bins "
        "(checked before the response's data are read). The brightest pixel is reported in "
        "degrees: RA/Dec on a celestial or HEALPix grid, else the instrument-frame zenith "
        "and azimuth.",
        epilog="examples: rotmod reconstruct folded.fits response.zarr -o image.fits "
        "--plot image.png;  rotmod reconstruct folded.fits sky.zarr --method mlem "
        "--max-iter 50 -o sky.fits --plot sky.png --mark-sky 201.5,-59.2",
    )
    p.add_argument("folded", metavar="FOLDED", help="folded profiles (FITS)")
    p.add_argument("response", metavar="RESPONSE",
                   help="response store (zarr, from rotmod response: a matrix or a Radon "
                   "table)")
    p.add_argument("--method", default=None, metavar="NAME",
                   help=f"algorithm ({', '.join(ALGORITHMS.names())}; default "
                   f"{DEFAULT_METHOD})")
    p.add_argument("--max-iter", type=count(1), default=None, metavar="N",
                   help="iteration limit (default: the method's)")
    p.add_argument("--fit-background", action="store_true",
                   help="fit a flat background per detector")
    p.add_argument("--uncertainty", type=count(0), default=0, metavar="N",
                   help="bootstrap N Poisson re-draws for a per-pixel uncertainty map")
    p.add_argument("--seed", type=count(0), default=0, help="seed (NCAR, bootstrap; default 0)")
    add_output(p, help="image (FITS)")
    add_progress(p)
    p.add_argument("--plot", default=None, metavar="PNG", help="also write a plot")
    p.add_argument("--mark", action="append", default=None, metavar="THETA,PHI",
                   type=source_arg(),
                   help="mark a true source position (instrument frame, deg) on the plot; "
                   "repeatable")
    p.add_argument("--mark-sky", action="append", default=None, metavar="RA,DEC",
                   help="mark a true source position (ICRS, deg) on the plot of a celestial "
                   "grid; repeatable")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    files = check_files({"FOLDED": args.folded, "RESPONSE": args.response},
                        {"--output": args.output, "--plot": args.plot}, args.overwrite,
                        plots=("--plot",))
    src, rsp, out, plot = (files[k] for k in ("FOLDED", "RESPONSE", "--output", "--plot"))
    if args.method is not None:
        registered(ALGORITHMS, args.method, "--method")
    marks = _marks(args)
    folded = read_folded(src)
    # The bins first, from the store's metadata alone: a mismatch costs no read of the
    # response's data (a matrix or a Radon table can take minutes to load).
    _, meta = open_store(as_store_path(rsp))
    n_time = int(meta["time_bins"]["n_bins"])
    if n_time != folded.n_bins:
        raise UserError(
            f"RESPONSE {str(rsp)!r} has {n_time} time bins (mask-angle bins per rotation) "
            f"but FOLDED {str(src)!r} has {folded.n_bins}: they must be equal; fold with "
            f"--bins {n_time} or rebuild the response with --bins {folded.n_bins}"
        )
    _check_marks(marks, str((meta.get("grid") or {}).get("kind", "instrument")))
    warn_if_mirror_degenerate(folded.instrument, "rotmod reconstruct")
    response = open_response(rsp, instrument=folded.instrument)
    if isinstance(response, StoredResponse):
        response = response.materialise()  # a stored matrix: products from memory
    kw: dict[str, Any] = {}
    if args.max_iter is not None:
        kw["max_iter"] = args.max_iter
    if args.fit_background:
        kw["fit_background"] = True
    if args.uncertainty:
        kw.update(uncertainty="bootstrap", n_boot=args.uncertainty)
    with iteration_bar(progress_wanted(args), args.method or "reconstruct") as bar:
        if bar is not None:
            kw["callbacks"] = [lambda _solver, _it: bool(bar.update(1))]
        res = reconstruct(response, folded, args.method, seed=args.seed, **kw)
    info = {k: folded.meta[k] for k in ("telescop", "instrume", "obs_id") if k in folded.meta}
    if folded.energy_band is not None:
        info.update(folded.energy_band.to_dict())  # E_MIN, E_MAX of the image file
    write_image(out, res, overwrite=args.overwrite, seed=args.seed, command=args.command_line,
                meta={"folded": str(src), "response": str(rsp), **info,
                      "exposure": float(np.sum(folded.gti[:, 1] - folded.gti[:, 0]))})
    say(f"rotmod: {res.method}: {res.n_iter} iteration(s), stop: {res.stop_reason}, "
        f"chi2/dof {res.chi2_dof:.3g}, brightest pixel at "
        f"{describe_position(res.grid, int(np.argmax(res.image)))}")
    say(f"rotmod: wrote {out}")
    if plot is not None:
        use_agg()
        ax = plot_image(res.image, res.grid, sources=marks,
                        title=f"{res.method} ({response.metadata()['model']['model']})")
        save_figure(ax.figure, plot)
        say(f"rotmod: wrote {plot}")
    return 0


def _check_marks(marks: Any, kind: str) -> None:
    """Refuse, before any work, marks the plot of this grid kind cannot draw."""
    if marks is None:
        return
    if isinstance(marks, SkyCoord) and kind != "celestial":
        raise UserError(f"--mark-sky: sky positions are drawn on celestial images, but the "
                        f"response's grid is {kind!r}"
                        + ("; use --mark THETA,PHI" if kind == "instrument" else ""))
    if not isinstance(marks, SkyCoord) and kind != "instrument":
        raise UserError(f"--mark: instrument-frame positions are drawn on instrument-frame "
                        f"images, but the response's grid is {kind!r}"
                        + ("; use --mark-sky RA,DEC" if kind == "celestial" else ""))


def _marks(args: argparse.Namespace) -> Any:
    """The plot's true sources: ``(theta, phi)`` (deg) of ``--mark`` or a SkyCoord of
    ``--mark-sky`` (checked before any work)."""
    if args.mark and args.mark_sky:
        raise UserError("--mark and --mark-sky: give one kind of position (instrument frame "
                        "or sky) for one plot")
    if args.mark:
        m = np.array(args.mark)  # deg, checked by argparse
        return (m[:, 0], m[:, 1])
    if args.mark_sky:
        radec = np.array([parse_radec(t, "--mark-sky") for t in args.mark_sky])
        return SkyCoord(radec[:, 0] * u.deg, radec[:, 1] * u.deg)
    return None
