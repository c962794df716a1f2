"""``rotmod detect``: the sources in the data -> catalogue, TS map, regions, HEALPix maps."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from rotmod.cli._common import (
    UserError,
    add_output,
    add_progress,
    check_files,
    count,
    progress_wanted,
    quantity,
    say,
)
from rotmod.cli._response import add_grid_options, make_grid
from rotmod.cli._sources import (
    add_data_options,
    folded_of,
    input_files,
    make_response,
    read_data,
    stored_frame,
)
from rotmod.io.catalogue import read_catalogue, write_detection
from rotmod.io.regions import write_ds9, write_probability_map
from rotmod.io.tables import product_format
from rotmod.io.tsmaps import write_ts_map
from rotmod.response.parallel import Progress
from rotmod.sources import Detection, detect
from rotmod.sources.catalogue import probability_map, read_sky_model


def register(sub: Any) -> None:
    p = sub.add_parser(
        "detect",
        help="find the sources in the data -> catalogue, TS map, regions",
        description="Detect point sources in an event list or folded profiles: the "
        "iterative search (a TS map of a test source, the peak added and every source, "
        "position and background refitted, until no peak passes --threshold), then each "
        "source's TS, flux with profile-likelihood errors and upper limit, and localisation "
        "region. Writes the catalogue (FITS, or ECSV for a name ending .ecsv; fluxes in "
        "photons/s on one unmasked detector face), and on request the residual TS map "
        "(TS, SQRT_TS, FLUX, FLUX_ERR, FLUX_UL and SENSITIVITY against the final model: "
        "what is left, with limits where nothing was found), the first TS map (against the "
        "background and the --catalogue-in sources), and for a grid on the sky a DS9 "
        "region file (ICRS) and a HEALPix probability map per source. The response is "
        "a stored one (--response) or built here on the grid of the options, as rotmod "
        "response builds it.",
        epilog="examples: rotmod detect events.fits -i prototype -e 122 --fov 10 --pixel 0.5 "
        "-m exact -o sources.fits --ts-map ts.fits;  rotmod detect folded.fits --response "
        "sky.zarr -o sources.ecsv --regions sources.reg --prob-maps prob_;  rotmod detect "
        "events.fits -e 122 --grid celestial --fov 6 --pixel 0.25 --catalogue-in known.fits "
        "-o all.fits",
    )
    add_data_options(p)
    add_grid_options(p)
    p.add_argument("--threshold", type=float, default=25.0, metavar="TS",
                   help="TS a peak of the map must reach to be added (default 25: 5 sigma at "
                   "a fixed position; the maximum over a map needs more for the same false "
                   "rate)")
    p.add_argument("--max-sources", type=count(0), default=50, metavar="N",
                   help="stop after adding N sources (default 50)")
    p.add_argument("--systematic", type=quantity("deg"), default=0.0, metavar="DEG",
                   help="systematic position error per axis folded into the regions (deg; "
                   "default 0)")
    p.add_argument("--ul-confidence", type=float, default=0.95, metavar="CL",
                   help="confidence of the flux upper limits (default 0.95)")
    p.add_argument("--exact-above", type=float, default=None, metavar="TS",
                   help="screen every TS map with the score test (three sky-wide products) "
                   "and compute the likelihood ratio only where TS nears TS: minutes instead "
                   "of hours for 10^6-pixel fields (default: every pixel exact)")
    p.add_argument("--catalogue-in", default=None, metavar="FILE",
                   help="known sources to start from (a catalogue, FITS or ECSV, with RA/DEC "
                   "or THETA/PHI columns): kept and refitted")
    p.add_argument("--refit-positions", action="store_true",
                   help="with --catalogue-in: fit the known sources' positions too (default "
                   "held)")
    add_output(p, help="source catalogue (FITS; ECSV if the name ends .ecsv)")
    p.add_argument("--ts-map", default=None, metavar="FITS",
                   help="also write the residual TS map (every map, in the grid's FITS form)")
    p.add_argument("--first-map", default=None, metavar="FITS",
                   help="also write the first TS map (before any source was added)")
    p.add_argument("--regions", default=None, metavar="REG",
                   help="also write the regions as a DS9 file (ICRS; grids on the sky only)")
    p.add_argument("--prob-maps", default=None, metavar="PREFIX",
                   help="also write a HEALPix probability map per source, PREFIX + NAME + "
                   ".fits (grids on the sky only)")
    add_progress(p)
    p.set_defaults(func=run)


def _pixel_counter(bar: Progress) -> Any:
    """A ``progress(done, total)`` callback counting the pixels of every TS map on one bar
    (each map counts from 0 again)."""
    last = [0, 0]

    def progress(done: int, total: int) -> None:
        fresh = last[0] >= last[1]  # the previous map was finished: a new one starts
        bar.update(done if fresh else done - last[0])
        last[:] = [done, total]

    return progress


def _describe(det: Detection, k: int) -> str:
    s = det.result.model.sources[k]
    r = det.regions[k]
    if s.frame == "celestial":
        where = f"RA {s.position.ra.deg:.3f} deg, Dec {s.position.dec.deg:+.3f} deg"
    else:
        where = f"theta {s.position[0]:.3f} deg, phi {s.position[1]:.3f} deg"
    lo, hi = det.result.flux_err[k]
    r90 = f", r90 {r.radius(0.9):.3g} deg" if r is not None else ""
    return (f"rotmod: {s.name}: {where}, TS {det.result.ts[k]:.1f}, flux {s.flux:.4g} "
            f"-{lo:.2g} +{hi:.2g} 1/s{r90}")


def run(args: argparse.Namespace) -> int:
    maps = {f"--{opt.replace('_', '-')}": getattr(args, opt)
            for opt in ("ts_map", "first_map", "regions")}
    files = check_files(input_files(args, **{"--catalogue-in": args.catalogue_in}),
                        {"--output": args.output, **maps}, args.overwrite)
    data_path, out = files["DATA"], files["--output"]
    product_format(out, "--output")
    extra = {opt: files[f"--{opt.replace('_', '-')}"]
             for opt in ("ts_map", "first_map", "regions") if getattr(args, opt) is not None}
    if not (np.isfinite(args.threshold) and args.threshold > 0):
        raise UserError(f"--threshold: must be a TS > 0, got {args.threshold:g}")
    if not args.systematic >= 0:
        raise UserError(f"--systematic: must be >= 0 deg, got {args.systematic:g}")
    if not 0.5 < args.ul_confidence < 1:
        raise UserError(f"--ul-confidence: must be in (0.5, 1), got {args.ul_confidence:g}")
    if args.refit_positions and args.catalogue_in is None:
        raise UserError("--refit-positions: goes with --catalogue-in")
    frame = stored_frame(args) or ("instrument" if args.grid == "instrument" else "celestial")
    if frame == "instrument":
        for opt in ("regions", "prob_maps"):
            if getattr(args, opt) is not None:
                raise UserError(
                    f"--{opt.replace('_', '-')}: DS9 regions and HEALPix maps are on the sky, "
                    "but this grid is in the instrument frame (no sky position without the "
                    "attitude); use --grid celestial or healpix")
    if args.prob_maps is not None and not Path(args.prob_maps).parent.is_dir():
        raise UserError(f"--prob-maps: folder {str(Path(args.prob_maps).parent)!r} does not "
                        "exist")

    # The known sources are read before any work: a bad catalogue costs nothing.
    known = read_catalogue(args.catalogue_in) if args.catalogue_in is not None else None
    data = read_data(args)
    response = make_response(args, data, lambda att: make_grid(args, att), "rotmod detect")
    folded = folded_of(data, response.time_bins, args)
    model = (read_sky_model(known, free_positions=args.refit_positions, response=response)
             if known is not None else None)
    n_known = 0 if model is None else len(model.sources)
    say(f"rotmod: detect: {response.n_det} detector(s) x {response.n_time} bins, "
        f"{response.n_sky} pixels ({response.grid.kind} grid), threshold TS "
        f"{args.threshold:g}{f', {n_known} known source(s)' if n_known else ''}")
    kw = {"model": model, "threshold": args.threshold, "max_sources": args.max_sources,
          "systematic": args.systematic, "ul_confidence": args.ul_confidence,
          "exact_above": args.exact_above}
    if progress_wanted(args):
        with Progress(None, "detect: TS maps", "pixel", tty=sys.stderr.isatty()) as bar:
            det = detect(response, folded, progress=_pixel_counter(bar), **kw)
    else:
        det = detect(response, folded, **kw)
    names = [s.name for s in det.sources]
    prob_paths = {}
    if args.prob_maps is not None:
        if len(set(names)) != len(names):
            raise UserError(f"--prob-maps: the sources' names must differ to name their "
                            f"files, got {names}")
        keys = {k: f"--prob-maps file {k + 1}" for k in range(len(names))
                if det.regions[k] is not None}
        files = files.more({keys[k]: f"{args.prob_maps}{names[k]}.fits" for k in keys})
        prob_paths = {k: files[key] for k, key in keys.items()}

    say(f"rotmod: {len(det.sources) - n_known} new source(s) with TS >= {args.threshold:g}"
        + (f" (and {n_known} known)" if n_known else ""))
    for k in range(len(det.sources)):
        say(_describe(det, k))
    if np.isfinite(det.confusion):
        say(f"rotmod: confusion noise {det.confusion:.2f} sigma on the residual map "
            f"(catalogue column TS_CONF = TS / {1 + det.confusion**2:.3g})")
    provenance = {"command": args.command_line}
    meta = {"data": str(data_path), **({"response": str(args.response)}
                                       if args.response else {})}
    write_detection(det, out, overwrite=args.overwrite, meta=meta, **provenance)
    say(f"rotmod: wrote {out}")
    writers = {"ts_map": lambda p: write_ts_map(det.ts_map, p, overwrite=args.overwrite,
                                                meta=meta, **provenance),
               "first_map": lambda p: write_ts_map(det.first_map, p, overwrite=args.overwrite,
                                                   meta=meta, **provenance),
               "regions": lambda p: write_ds9(det.regions, p, overwrite=args.overwrite)}
    for opt, path in extra.items():
        writers[opt](path)
        say(f"rotmod: wrote {path}")
    for k, path in prob_paths.items():
        write_probability_map(probability_map(det.regions[k]), path, overwrite=args.overwrite,
                              meta=meta, **provenance)
        say(f"rotmod: wrote {path}")
    return 0
