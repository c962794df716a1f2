"""``rotmod fold``: an event list folded into count profiles per detector."""

from __future__ import annotations

import argparse
from typing import Any

from rotmod.binning import TimeBinning
from rotmod.cli._common import (
    BINS_HELP,
    DEFAULT_BINS,
    UserError,
    add_band,
    add_output,
    band_of,
    check_files,
    count,
    save_figure,
    say,
    use_agg,
)
from rotmod.events import fold
from rotmod.io import read_events, write_folded


def register(sub: Any) -> None:
    p = sub.add_parser(
        "fold",
        help="event list -> folded profiles (FITS)",
        description="Fold a FITS event list modulo the mask rotation period into count "
        "profiles per detector (counts, exposure per bin) and write them as FITS.",
        epilog="example: rotmod fold events.fits -o folded.fits  (then rotmod reconstruct "
        "folded.fits response.zarr ..., with a response of the same --bins)",
    )
    p.add_argument("events", metavar="EVENTS", help="event list (FITS, from rotmod simulate)")
    p.add_argument("-n", "--bins", type=count(1), default=DEFAULT_BINS, metavar="N",
                   help=BINS_HELP)
    add_band(p)
    add_output(p, help="folded profiles (FITS)")
    p.add_argument("--plot", default=None, metavar="PNG", help="also plot the count rates")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:

    files = check_files({"EVENTS": args.events},
                        {"--output": args.output, "--plot": args.plot}, args.overwrite,
                        plots=("--plot",))
    src, out, plot = files["EVENTS"], files["--output"], files["--plot"]
    if args.bins < 1:
        raise UserError(f"--bins: must be >= 1, got {args.bins}")
    events = read_events(src)
    band = band_of(args.band)
    folded = fold(events, TimeBinning(args.bins), band)
    write_folded(folded, out, overwrite=args.overwrite, command=args.command_line)
    say(f"rotmod: wrote {out} ({folded.counts.shape[0]} detector(s) x {folded.n_bins} bins, "
        f"{int(folded.counts.sum())} counts)")
    if plot is not None:
        use_agg()
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 3))
        deg = folded.bin_centers.to_value("deg")
        for d in range(min(folded.counts.shape[0], 7)):
            ax.errorbar(deg, folded.rate[d], folded.error[d], fmt=".", ms=2, lw=0.5,
                        label=f"detector {d}")
        ax.set_xlabel("mask angle ξ (deg)")
        ax.set_ylabel("count rate (1/s)")
        ax.legend(fontsize=6)
        save_figure(fig, plot)
        say(f"rotmod: wrote {plot}")
    return 0
