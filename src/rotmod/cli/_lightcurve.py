"""``rotmod lightcurve``: fluxes of catalogued sources per time interval -> a table (+ plot)."""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from rotmod.cli._common import (
    UserError,
    add_output,
    add_progress,
    band_of,
    check_files,
    count,
    progress_wanted,
    save_figure,
    say,
    to_number,
    tqdm_progress,
    use_agg,
)
from rotmod.cli._sources import add_data_options, input_files, make_response, read_data
from rotmod.io.catalogue import read_catalogue
from rotmod.io.tables import product_format, write_light_curve
from rotmod.limits import check_memory
from rotmod.sky import DirectionList, PositionList, SkyGeometry
from rotmod.sources.catalogue import read_sky_model
from rotmod.sources.lightcurve import LightCurve, light_curve


def register(sub: Any) -> None:
    p = sub.add_parser(
        "lightcurve",
        help="fluxes of catalogued sources per time interval -> table + plot",
        description="Fit the fluxes of the sources of a catalogue (positions held; e.g. "
        "from rotmod detect) in each time interval of an event list, with every "
        "detector's background refitted per interval, and write one row per interval "
        "(time_min, time_max, exposure, flux, flux_errn, flux_errp, flux_ul, ts, sqrt_ts; "
        "one entry per source in each flux column, fluxes in photons/s on one unmasked "
        "detector face) as FITS or ECSV. An interval without good time has exposure 0 and "
        "NaN values. The response is built at the catalogue's positions (or --response).",
        epilog="examples: rotmod lightcurve events.fits sources.fits -e 122 --intervals 10 "
        "-o lc.fits --plot lc.png;  rotmod lightcurve events.fits sources.ecsv -i prototype "
        "--edges 0,300,600,1200 -o lc.ecsv",
    )
    add_data_options(p, events_only=True)
    p.add_argument("catalogue", metavar="CATALOGUE",
                   help="the sources (FITS or ECSV catalogue with RA/DEC or THETA/PHI "
                   "columns, e.g. from rotmod detect)")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--intervals", type=count(1), default=None, metavar="N",
                   help="N equal time intervals over the observation")
    g.add_argument("--edges", default=None, metavar="T0,T1,...",
                   help="interval edges (s, the event list's time), increasing")
    p.add_argument("--ul-confidence", type=float, default=0.95, metavar="CL",
                   help="confidence of the flux upper limits (default 0.95)")
    add_output(p, help="light curve (FITS; ECSV if the name ends .ecsv)")
    p.add_argument("--plot", default=None, metavar="PNG", help="also plot the light curve")
    add_progress(p)
    p.set_defaults(func=run)


def _given_edges(args: argparse.Namespace) -> np.ndarray | None:
    """The ``--edges`` (checked before any file is read), or None with ``--intervals``."""
    if args.edges is not None:
        try:
            edges = np.array([to_number(x, "s") for x in args.edges.split(",")])
        except argparse.ArgumentTypeError as exc:
            raise UserError(f"--edges: must be times T0,T1,... (s), got {args.edges!r}: "
                            f"{exc}") from None
        if edges.size < 2 or np.any(np.diff(edges) <= 0):
            raise UserError(f"--edges: must be at least two increasing times (s), got "
                            f"{args.edges!r}")
        return edges
    return None


def _plot(lc: LightCurve, path: Any) -> None:
    use_agg()
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    mid = 0.5 * (lc.time_edges[:-1] + lc.time_edges[1:])
    half = 0.5 * np.diff(lc.time_edges)
    for j, name in enumerate(lc.names):
        # Below TS 4 (2 sigma) an interval shows its upper limit, above it the flux.
        seen = lc.ts[:, j] >= 4.0
        bar = ax.errorbar(mid[seen], lc.flux[seen, j], yerr=lc.flux_err[seen, j].T,
                          xerr=half[seen], fmt="o", ms=3, label=name)
        ax.errorbar(mid[~seen], lc.flux_ul[~seen, j], xerr=half[~seen], yerr=0.0,
                    fmt="v", ms=4, color=bar[0].get_color(), alpha=0.6)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("flux (photons/s per detector face)")
    ax.set_title(f"light curve (triangles: {lc.ul_confidence:.0%} upper limits, TS < 4)",
                 fontsize=9)
    ax.legend(fontsize=7)
    save_figure(fig, path)


def run(args: argparse.Namespace) -> int:
    files = check_files(input_files(args, events_only=True, CATALOGUE=args.catalogue),
                        {"--output": args.output, "--plot": args.plot}, args.overwrite,
                        plots=("--plot",))
    cat_path, out, plot = files["CATALOGUE"], files["--output"], files["--plot"]
    product_format(out, "--output")
    if not 0.5 < args.ul_confidence < 1:
        raise UserError(f"--ul-confidence: must be in (0.5, 1), got {args.ul_confidence:g}")
    given = _given_edges(args)
    events = read_data(args, events_only=True)
    catalogue = read_catalogue(cat_path)
    if not len(catalogue):
        raise UserError(f"CATALOGUE {str(cat_path)!r} has no sources")
    gti = np.asarray(events.gti, dtype=float)
    n = args.intervals if given is None else given.size - 1
    # Per interval: its edges and pair (~130 B) and per source 5 results of 8 B.
    check_memory(n * (130.0 + 40.0 * len(catalogue)),
                 f"a light curve of {n} intervals x {len(catalogue)} source(s)",
                 hint="ask for fewer --intervals")
    edges = (np.linspace(float(gti[0, 0]), float(gti[-1, 1]), n + 1) if given is None
             else given)
    # The intervals tile [edges[0], edges[-1]]: one holds good time if that span does.
    if not np.any((gti[:, 0] < edges[-1]) & (gti[:, 1] > edges[0])):
        raise UserError(f"--edges: no interval overlaps the events' good time "
                        f"({gti[0, 0]:g} .. {gti[-1, 1]:g} s)")

    def grid_of(att: Any) -> SkyGeometry:
        # The response of the catalogue's positions only: one column per source.
        if catalogue.frame == "instrument":
            return DirectionList(*catalogue.positions)
        if att is None:
            raise UserError("CATALOGUE: sources on the sky need the attitude: --pointing "
                            "RA,DEC [--roll DEG] or --attitude FILE (the event file records "
                            "none)")
        return PositionList.from_coords(catalogue.positions, att)

    response = make_response(args, events, grid_of, "rotmod lightcurve")
    model = read_sky_model(catalogue, response=response)
    say(f"rotmod: light curve of {len(model.sources)} source(s) over {edges.size - 1} "
        f"interval(s), {response.n_det} detector(s) x {response.n_time} bins")
    kw = {"energy_band": band_of(args.band), "ul_confidence": args.ul_confidence}
    if progress_wanted(args):
        update, close = tqdm_progress(edges.size - 1, "light curve", "interval")
        try:
            lc = light_curve(response, events, model, edges, progress=update, **kw)
        finally:
            close()
    else:
        lc = light_curve(response, events, model, edges, **kw)
    write_light_curve(lc, out, overwrite=args.overwrite, command=args.command_line,
                      meta={"events": str(args.data), "catalog": str(cat_path)})
    say(f"rotmod: wrote {out} ({edges.size - 1} rows, {np.count_nonzero(lc.exposure)} with "
        "good time)")
    if plot is not None:
        _plot(lc, plot)
        say(f"rotmod: wrote {plot}")
    return 0
