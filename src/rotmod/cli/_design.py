"""``rotmod design``: the mask design trade-off (sensitivity, resolving power, transmission)."""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from rotmod import design
from rotmod.cli._common import (
    UserError,
    add_instrument,
    add_output,
    add_progress,
    check_files,
    count,
    load_config,
    parse_range,
    progress_wanted,
    quantity,
    save_figure,
    say,
    tqdm_progress,
    use_agg,
    write_table,
)
from rotmod.plotting.design import plot_design_tradeoff


def _weights(text: str) -> tuple[float, float, float]:
    try:
        w = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be three numbers S,T,R, got {text!r}") from None
    if len(w) != 3 or min(w) < 0 or sum(w) <= 0:
        raise argparse.ArgumentTypeError(
            f"must be three numbers >= 0 with a positive sum (S,T,R), got {text!r}"
        )
    return w  # type: ignore[return-value]


def register(sub: Any) -> None:
    p = sub.add_parser(
        "design",
        help="mask design trade-off: Pareto front of sensitivity, resolution, transmission",
        description="Scan slat width a and gap b (and thickness h) for a detector size, mask "
        "height L, material, energy band and field of view; compute with the exact model the "
        "sensitivity (std of the profile over a rotation), transmission (mean profile) and "
        "resolving power (arctan b/L), averaged over the field and energies; report the Pareto "
        "front, whether each design is inside the advanced model's validity "
        "(min a'(t), min b'(t) >= 0), and the best design for the given weights.",
        epilog="example: rotmod design -i prototype --a 2:8:7 --b 2:8:7 --h 2 --fov 20 "
        "--energies 122,662 -o design.ecsv --plot design.png. Ranges are START:STOP:NUM "
        "(inclusive) or comma lists, in cm / keV.",
    )
    add_instrument(p)
    p.add_argument("--a", type=parse_range, default=None, metavar="RANGE",
                   help="slat widths to scan (cm; default 0.5c:2c:7)")
    p.add_argument("--b", type=parse_range, default=None, metavar="RANGE",
                   help="slat gaps to scan (cm; default 0.5c:2c:7)")
    p.add_argument("--h", type=parse_range, default=None, metavar="RANGE",
                   help="slat thicknesses (cm; default the instrument's)")
    p.add_argument("--c", type=quantity("cm"), default=None, metavar="CM",
                   help="detector diameter (cm; default the instrument's)")
    p.add_argument("--L", type=quantity("cm"), default=None, metavar="CM",
                   help="mask height (cm; default the instrument's)")
    p.add_argument("--energies", type=parse_range, default=None, metavar="RANGE",
                   help="energies (keV) averaged over (default the instrument's)")
    p.add_argument("--fov", type=quantity("deg"), default=20.0, metavar="DEG",
                   help="full field of view (deg; default 20)")
    p.add_argument("--weights", type=_weights, default=(1.0, 1.0, 1.0), metavar="S,T,R",
                   help="weights of sensitivity, transmission, resolving power for the best "
                   "design (default 1,1,1)")
    p.add_argument("--require-advanced", action="store_true",
                   help="choose the best design among those valid for the advanced model")
    p.add_argument("--angles", type=count(1), default=64, metavar="N",
                   help="mask angles over half a turn (default 64)")
    p.add_argument("--rings", type=count(1), default=3, metavar="N",
                   help="zenith rings sampling the field (default 3)")
    p.add_argument("--azimuths", type=count(1), default=4, metavar="N",
                   help="azimuths per ring (default 4)")
    add_progress(p)
    add_output(p, help="table (.ecsv or .csv)")
    p.add_argument("--plot", default=None, metavar="PNG", help="also write the trade-off plot")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    files = check_files({"--instrument": args.instrument},
                        {"--output": args.output, "--plot": args.plot}, args.overwrite,
                        plots=("--plot",))
    out, plot = files["--output"], files["--plot"]
    cfg = load_config(args)
    inst = cfg.to_instrument()
    c = inst.detectors.diameter if args.c is None else args.c
    L = inst.mask.height if args.L is None else args.L
    a = np.linspace(0.5 * c, 2 * c, 7) if args.a is None else args.a
    b = np.linspace(0.5 * c, 2 * c, 7) if args.b is None else args.b
    h = np.array([inst.mask.thickness]) if args.h is None else args.h
    e = cfg.energies_kev if args.energies is None else args.energies
    n = a.size * b.size * h.size
    if n > 20000:
        raise UserError(f"--a/--b/--h: {n} designs is too many for one scan (max 20000)")
    update, close = (tqdm_progress(n, "designs", "design") if progress_wanted(args)
                     else (None, lambda: None))
    try:
        # Looked up on the module at each call (tests replace it to provoke an unexpected error).
        scan = design.scan_designs(
            detector_diameter=c, height=L, slat_width=a, slat_gap=b, thickness=h,
            material=inst.mask.material, energies=e, fov=args.fov, mu=inst.mask.mu,
            n_theta=args.rings, n_phi=args.azimuths, n_angles=args.angles, progress=update,
        )
    finally:
        close()
    best = scan.best(args.weights, require_advanced=args.require_advanced)
    table = scan.to_table(args.weights)
    table.meta["best_index"] = best
    table.meta["require_advanced"] = bool(args.require_advanced)
    write_table(table, out)
    front = np.flatnonzero(scan.pareto)
    print(f"{len(scan)} designs scanned in {scan.run_time:.2f} s (exact model; "
          f"c = {c:g} cm, L = {L:g} cm, {inst.mask.material.name}, "
          f"E = {', '.join(f'{x:g}' for x in np.atleast_1d(e))} keV, FOV {args.fov:g} deg)")
    print(f"Pareto front: {front.size} designs")
    print(f"{'a':>6} {'b':>6} {'h':>6} {'sens':>7} {'trans':>7} {'res':>7} {'adv':>4}")
    for i in front:
        mark = " <- best" if i == best else ""
        print(f"{scan.slat_width[i]:6.3g} {scan.slat_gap[i]:6.3g} {scan.thickness[i]:6.3g} "
              f"{scan.sensitivity[i]:7.4f} {scan.transmission[i]:7.4f} "
              f"{scan.resolution_deg[i]:6.3f}° {'yes' if scan.advanced_valid[i] else 'no':>4}"
              f"{mark}")
    w = args.weights
    print(f"best for weights sensitivity/transmission/resolution = {w[0]:g}/{w[1]:g}/{w[2]:g}: "
          f"a = {scan.slat_width[best]:g} cm, b = {scan.slat_gap[best]:g} cm, "
          f"h = {scan.thickness[best]:g} cm")
    say(f"rotmod: wrote {out}")
    if plot is not None:
        use_agg()

        ax = plot_design_tradeoff(scan, weights=args.weights, best=best)
        save_figure(ax.figure, plot)
        say(f"rotmod: wrote {plot}")
    return 0
