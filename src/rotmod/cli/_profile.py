"""``rotmod profile``: characteristic profiles of chosen sources and models."""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
from astropy.table import Table

from rotmod.cli._common import (
    UserError,
    add_energy,
    add_instrument,
    add_output,
    check_files,
    count,
    energy_of,
    load_config,
    registered,
    save_figure,
    say,
    source_arg,
    use_agg,
    write_table,
)
from rotmod.errors import ModelValidityError
from rotmod.limits import check_memory
from rotmod.montecarlo import simulate_profiles
from rotmod.plotting.profiles import plot_profiles
from rotmod.profiles import DEFAULT_COMPARISON, DEFAULT_MODEL, MODELS, get_model


def register(sub: Any) -> None:
    p = sub.add_parser(
        "profile",
        help="profiles of chosen sources and models (table + plot)",
        description="Compute characteristic count-rate profiles P(xi) of point sources with "
        "one or more models and write them as a table (ECSV or CSV, long format: model, "
        "detector, source, mask angle, profile) and a PNG plot.",
        epilog="example: rotmod profile -i prototype --source 6,30 --source 48,0 "
        "-o profiles.ecsv --plot profiles.png",
    )
    add_instrument(p)
    add_energy(p)
    p.add_argument("-s", "--source", action="append", type=source_arg(), required=True,
                   metavar="THETA,PHI", help="source zenith and azimuth (deg); repeatable")
    p.add_argument("-m", "--model", action="append", default=None, metavar="NAME",
                   help=f"profile model ({', '.join(MODELS.names())}); repeatable; default "
                   f"{', '.join(DEFAULT_COMPARISON)}, skipping those that do not apply to the "
                   "geometry")
    p.add_argument("--angles", type=count(1), default=360, metavar="N",
                   help="mask angles over one turn (default 360)")
    p.add_argument("--detector", type=count(0), default=None, metavar="D",
                   help="only this detector (index); default all in the table, 0 in the plot")
    p.add_argument("--mc-photons", type=count(0), default=0, metavar="N",
                   help="also run the Monte Carlo with N photons per angle (default 0: no)")
    p.add_argument("--seed", type=count(0), default=0, help="Monte Carlo seed (default 0)")
    add_output(p, help="table file (.ecsv or .csv)")
    p.add_argument("--plot", default=None, metavar="PNG", help="also write a plot")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    files = check_files({"--instrument": args.instrument},
                        {"--output": args.output, "--plot": args.plot}, args.overwrite,
                        plots=("--plot",))
    out, plot = files["--output"], files["--plot"]
    if args.angles < 1:
        raise UserError(f"--angles: must be >= 1, got {args.angles}")
    cfg = load_config(args)
    inst = cfg.to_instrument()
    energy = energy_of(args, cfg)
    n_det = len(inst.detectors)
    dets = list(range(n_det))
    if args.detector is not None:
        if not 0 <= args.detector < n_det:
            raise UserError(f"--detector: must be in 0..{n_det - 1}, got {args.detector}")
        dets = [args.detector]
    src = np.array(args.source, dtype=float)
    theta, phi = src[:, 0], src[:, 1]  # deg, the library's meaning of a plain angle

    # Every model's profiles plus the table's rows (~10 columns) for each of them.
    n_models = len(args.model or DEFAULT_COMPARISON) + (args.mc_photons > 0)
    check_memory(8.0 * args.angles * n_det * len(src) * 11 * n_models,
                 f"profiles of {n_det} detectors x {args.angles} angles x {len(src)} sources",
                 hint="ask for fewer --angles")
    xi = (np.arange(args.angles) + 0.5) * (360.0 / args.angles)
    explicit = args.model is not None
    names = [registered(MODELS, n, "--model")
             for n in dict.fromkeys(args.model or DEFAULT_COMPARISON)]
    profiles: dict[str, np.ndarray] = {}
    for n in names:
        try:
            profiles[n] = get_model(n).profile(inst, theta, phi, xi, energy)
        except ModelValidityError as exc:
            if explicit:
                raise
            say(f"rotmod: note: model {n!r} skipped: {exc}")
    if not profiles:
        # The default model is valid for every geometry (rotmod.profiles.DEFAULT_MODEL).
        raise UserError(f"no model applies to this geometry; ask for --model {DEFAULT_MODEL}")
    mc = None
    if args.mc_photons > 0:
        mc = simulate_profiles(inst, theta, phi, xi, energy=energy, n_photons=args.mc_photons,
                               seed=args.seed)
        profiles_mc = {"montecarlo": mc.fraction}
    else:
        profiles_mc = {}

    rows: dict[str, list] = {k: [] for k in
                             ("model", "detector", "source", "theta", "phi", "xi", "profile")}
    for name, P in {**profiles, **profiles_mc}.items():
        for d in dets:
            for s in range(src.shape[0]):
                rows["model"] += [name] * xi.size
                rows["detector"] += [d] * xi.size
                rows["source"] += [s] * xi.size
                rows["theta"] += [src[s, 0]] * xi.size
                rows["phi"] += [src[s, 1]] * xi.size
                rows["xi"] += xi.tolist()
                rows["profile"] += P[d, :, s].tolist()
    t = Table(rows)
    for col in ("theta", "phi", "xi"):
        t[col].unit = "deg"
    t.meta.update({"instrument": inst.to_dict(), "energy_keV": energy,
                   "models": list(profiles), "mc_photons": int(args.mc_photons)})
    write_table(t, out)
    say(f"rotmod: wrote {out} ({len(t)} rows: {len(profiles)} model(s), {len(dets)} "
        f"detector(s), {src.shape[0]} source(s), {xi.size} angles)")
    if plot is not None:
        use_agg()
        import matplotlib.pyplot as plt

        d = dets[0]
        fig, axes = plt.subplots(src.shape[0], 1, figsize=(7, 2.6 * src.shape[0]),
                                 squeeze=False)
        for s in range(src.shape[0]):
            plot_profiles(
                xi, {n: P[d, :, s] for n, P in profiles.items()},
                mc=None if mc is None else mc.fraction[d, :, s],
                mc_error=None if mc is None else mc.error[d, :, s],
                title=(f"θ = {src[s, 0]:g}°, φ = {src[s, 1]:g}°, detector {d}, "
                       f"{energy:g} keV ({cfg.name or args.instrument})"),
                ax=axes[s, 0],
            )
        fig.tight_layout()
        save_figure(fig, plot)
        say(f"rotmod: wrote {plot}")
    return 0
