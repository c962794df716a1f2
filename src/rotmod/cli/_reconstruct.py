"""``rotmod reconstruct``: folded profiles + a stored response -> FITS image and plot."""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from rotmod.cli._common import (
    UserError,
    add_output,
    add_progress,
    check_input,
    check_output,
    check_plot,
    count,
    iteration_bar,
    progress_wanted,
    registered,
    save_figure,
    say,
    source_arg,
    use_agg,
)
from rotmod.io import read_folded
from rotmod.io.images import write_image
from rotmod.plotting.images import plot_image
from rotmod.reconstruction import ALGORITHMS, reconstruct
from rotmod.reconstruction.api import DEFAULT_METHOD
from rotmod.response import StoredResponse, open_response


def register(sub: Any) -> None:
    p = sub.add_parser(
        "reconstruct",
        help="folded profiles + response -> FITS image + plot",
        description="Reconstruct a sky image from folded count profiles (rotmod fold) with a "
        "stored response (rotmod response), and write it as FITS (with WCS) and optionally a "
        "PNG plot. The response must have been computed for the data's instrument and number "
        "of bins.",
        epilog="example: rotmod reconstruct folded.fits response.zarr --method mlem "
        "-o image.fits --plot image.png",
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
                   help="mark a true source position on the plot (deg); repeatable")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    src = check_input(args.folded, "folded profiles")
    rsp = check_input(args.response, "response")
    out = check_output(args.output, args.overwrite, inputs=(src, rsp))
    plot = check_plot(args.plot, args.overwrite)
    if args.method is not None:
        registered(ALGORITHMS, args.method, "--method")
    folded = read_folded(src)
    response = open_response(rsp, instrument=folded.instrument)
    if response.n_time != folded.n_bins:
        raise UserError(
            f"{rsp}: the response has {response.n_time} time bins but {src} has "
            f"{folded.n_bins}; fold with --bins {response.n_time} or rebuild the response"
        )
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
    write_image(out, res, overwrite=args.overwrite,
                meta={"folded": str(src), "response": str(rsp), **info,
                      "exposure": float(np.sum(folded.gti[:, 1] - folded.gti[:, 0]))})
    peak = np.unravel_index(int(np.argmax(res.image)), res.image.shape)
    say(f"rotmod: {res.method}: {res.n_iter} iteration(s), stop: {res.stop_reason}, "
        f"chi2/dof {res.chi2_dof:.3g}, peak at pixel (iy, ix) = {tuple(int(v) for v in peak)}")
    say(f"rotmod: wrote {out}")
    if plot is not None:
        use_agg()

        marks = None
        if args.mark:
            m = np.array(args.mark)  # deg, checked by argparse
            marks = (m[:, 0], m[:, 1])
        ax = plot_image(res.image, res.grid, sources=marks,
                        title=f"{res.method} ({response.metadata()['model']['model']})")
        save_figure(ax.figure, plot)
        say(f"rotmod: wrote {plot}")
    return 0
