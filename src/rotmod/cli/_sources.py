"""What ``rotmod detect`` and ``rotmod lightcurve`` share: the data, and their response.

The data are an event list (folded here, with ``--bins`` and ``--band``) or folded profiles.
The response is a stored one (``--response STORE``, from ``rotmod response``; its bins must
be the data's) or built on the fly from the instrument (``-i``, default the one the data file
records), ``--energy``, ``--model`` and a sky geometry: the grid options of ``rotmod
response`` for a detection, the catalogue's positions for a light curve.  On the sky the
attitude is ``--pointing``/``--roll`` or an ``--attitude`` table (a drift: the
exposure-weighted response over its pieces), by default the pointing the event file records.
"""

from __future__ import annotations

import argparse
import logging
from typing import Any

import numpy as np

from rotmod.binning import TimeBinning
from rotmod.cli._common import (
    DEFAULT_BINS,
    UserError,
    add_attitude,
    add_band,
    add_energy,
    attitude_of,
    band_of,
    check_input,
    count,
    energy_of,
    intervals_of,
    registered,
    warn_if_mirror_degenerate,
)
from rotmod.events import EventList, FoldedProfiles, fold
from rotmod.io import read
from rotmod.io.config import list_presets, load_instrument_config
from rotmod.io.response_store import as_store_path, open_store
from rotmod.profiles import DEFAULT_MODEL, MODELS
from rotmod.response import ResponseOperator, StoredResponse, build_response, open_response
from rotmod.response.drift import drift_response
from rotmod.sky import Attitude, AttitudeTable, SkyGeometry

log = logging.getLogger("rotmod.cli")


def add_data_options(p: argparse.ArgumentParser, *, events_only: bool = False) -> None:
    """The data argument and the options that make their response (module notes)."""
    p.add_argument("data", metavar="EVENTS" if events_only else "DATA",
                   help="event list (FITS, from rotmod simulate)" if events_only else
                   "event list (FITS, from rotmod simulate; folded here) or folded profiles "
                   "(FITS, from rotmod fold)")
    p.add_argument("--response", default=None, metavar="STORE",
                   help="a stored response (zarr, from rotmod response) with the data's bins; "
                   "default: build one here from the options below")
    p.add_argument("-i", "--instrument", default=None, metavar="FILE|PRESET",
                   help="instrument description (TOML/YAML file) or preset name "
                   f"({', '.join(list_presets())}); default the instrument the data file "
                   "records")
    add_energy(p)
    p.add_argument("-m", "--model", default=None, metavar="NAME",
                   help=f"profile model of the response ({', '.join(MODELS.names())}; "
                   f"default {DEFAULT_MODEL})")
    p.add_argument("-n", "--bins", type=count(1), default=None, metavar="N",
                   help=f"an event list is folded into N mask-angle bins per rotation "
                   f"(default: the stored response's, else {DEFAULT_BINS} as in rotmod fold "
                   "and rotmod response)")
    add_band(p)
    add_attitude(p)


def input_files(args: argparse.Namespace, *, events_only: bool = False,
                **more: Any) -> dict[str, Any]:
    """The input files of :func:`add_data_options` (by the name a message gives them) and
    ``more``, for :func:`~rotmod.cli._common.check_files`."""
    return {"EVENTS" if events_only else "DATA": args.data, "--response": args.response,
            "--instrument": args.instrument, "--attitude": args.attitude, **more}


def read_data(args: argparse.Namespace, *, events_only: bool = False
              ) -> EventList | FoldedProfiles:
    """The ``DATA`` file: an event list, or (unless ``events_only``) folded profiles."""
    path = check_input(args.data, "EVENTS" if events_only else "DATA")
    data = read(path)
    kinds = (EventList,) if events_only else (EventList, FoldedProfiles)
    if not isinstance(data, kinds):
        raise UserError(f"{'EVENTS' if events_only else 'DATA'} {str(path)!r}: must be an "
                        f"event list{'' if events_only else ' or folded profiles'}, got a file "
                        f"of {type(data).__name__}")
    if isinstance(data, FoldedProfiles):
        for opt, given in (("--bins", args.bins), ("--band", args.band)):
            if given is not None:
                raise UserError(f"{opt}: applies to an event list; DATA {str(path)!r} is "
                                "folded already")
    return data


def stored_frame(args: argparse.Namespace) -> str | None:
    """The frame of the ``--response`` store's grid (``"celestial"`` or ``"instrument"``),
    from its metadata alone (before any work); None without ``--response``."""
    if args.response is None:
        return None
    _, meta = open_store(as_store_path(check_input(args.response, "--response")))
    kind = str((meta.get("grid") or {}).get("kind", "instrument"))
    return "instrument" if kind in ("instrument", "directions") else "celestial"


def attitude(args: argparse.Namespace, data: EventList | FoldedProfiles
             ) -> Attitude | AttitudeTable | None:
    """``--attitude``/``--pointing``, else the pointing the event file records."""
    att = attitude_of(args)
    if att is None and isinstance(data, EventList) and data.attitude is not None:
        att = data.attitude
        log.info("pointing RA %.4f Dec %+.4f roll %.2f deg from the event file (for a "
                 "drifting observation give its --attitude table)", att.ra, att.dec, att.roll)
    return att


def folded_of(data: EventList | FoldedProfiles, bins: TimeBinning,
              args: argparse.Namespace) -> FoldedProfiles:
    """The data folded with ``bins`` (folded profiles: checked to have them)."""
    if isinstance(data, EventList):
        return fold(data, bins, band_of(args.band))
    if not data.time_bins.same_bins(bins):
        raise UserError(f"DATA has {data.n_bins} time bins but the response "
                        f"{bins.n_bins}: they must be the same (fold with --bins "
                        f"{bins.n_bins}, or rebuild the response)")
    return data


def make_response(args: argparse.Namespace, data: EventList | FoldedProfiles,
                  grid_of: Any, what: str) -> ResponseOperator:
    """The stored response, or one built on the fly on ``grid_of(attitude)``'s geometry.

    ``grid_of(attitude)`` gives the sky geometry from the attitude (an ``Attitude`` or
    None; for a drift the mid-observation one).
    """
    if args.response is not None:
        store = check_input(args.response, "--response")
        for opt in ("instrument", "energy", "model"):
            if getattr(args, opt) is not None:
                raise UserError(f"--{opt}: the stored response has its own; give --{opt} "
                                "only to build a response here")
        response = open_response(store, instrument=data.instrument)
        if isinstance(response, StoredResponse):
            response = response.materialise()  # products from memory
        if isinstance(data, EventList) and args.bins is not None \
                and args.bins != response.n_time:
            raise UserError(f"--bins: the stored response has {response.n_time} bins, got "
                            f"--bins {args.bins}")
        return response
    if args.instrument is not None:
        cfg = load_instrument_config(args.instrument)
        inst = cfg.to_instrument()
        energy = energy_of(args, cfg)
    else:
        inst = data.instrument
        if args.energy is None:
            raise UserError("--energy: give the photon energy of the response (keV); the "
                            "data file does not record it (or give -i with the instrument "
                            "file, whose first energy is the default)")
        energy = energy_of(args, None)
    warn_if_mirror_degenerate(inst, what)
    model = registered(MODELS, args.model or DEFAULT_MODEL, "--model")
    if isinstance(data, FoldedProfiles):
        bins = data.time_bins
    else:
        bins = TimeBinning(args.bins or DEFAULT_BINS)
    att = attitude(args, data)
    if isinstance(att, AttitudeTable):
        gti = np.asarray(data.gti, dtype=float)
        intervals = intervals_of(att, float(gti[0, 0]), float(gti[-1, 1]), args.max_step)
        grid = grid_of(att.at(0.5 * (gti[0, 0] + gti[-1, 1])))
        _check_sky(grid, att)
        if model != "exact":
            # A summed drift matrix evaluates sources between pixels at one attitude only;
            # the per-piece Radon tables evaluate them with every piece.
            raise UserError(f"--model: a drifting observation (--attitude) is analysed with "
                            f"the exact model (kept per attitude piece), got {model!r}")
        return drift_response(inst, grid, bins, intervals, model, energy, operator="radon")
    grid = grid_of(att)
    _check_sky(grid, att)
    return build_response(inst, grid, bins, model, energy, dtype=np.float64)


def _check_sky(grid: SkyGeometry, att: Any) -> None:
    if grid.frame == "instrument" and att is not None and not isinstance(att, Attitude):
        raise UserError("--attitude: a drifting observation is analysed on the sky; use a "
                        "celestial or HEALPix grid (the instrument frame moves on the sky)")
