"""A simulated 4 h balloon flight with a varying altitude, imaged and spectrally fitted with
the time-variable background fitted (issue 23).

The flight: 4 h at Fort Sumner (NRLMSIS), floating at 38 km with a sunset-like dip to 32 km
in the middle (``h(t) = 38 - 3 (1 - cos(2 pi t / 4 h))`` km: over the 16 slices the column
above the balloon goes 4.0 -> 9.3 g/cm^2 and back).  A source of ``E^-2`` (K at 100 keV)
rises from hour angle -1 h to +3 h at declination 20 deg: its zenith angle goes 14.5 -> 42
deg, so its transmission through the air changes with both the altitude and the zenith angle.
The gondola tracks it: the source stays at one position in the instrument, (4.5, 2.5) deg in
the grid's tangent plane (5.15 deg off axis).

``--pointing zenith``: the gondola points at the zenith instead and the sky drifts through
the field.  The source (declination 3 deg north of the zenith) transits at mid-flight: its
angle from the axis, its zenith angle, goes 24.3 -> 3.0 -> 24.3 deg, so both its modulation
and its path through the air change minute by minute.  The attitude is sampled every
``--step`` s (default 60 s, one turn); each slice is a drift response over its own
intervals (:func:`rotmod.response.drift.drift_response` on a 15 x 15 deg celestial grid
centred on the source) and the spectral columns are one per slice
(:func:`rotmod.sources.spectra.spectral_columns` of the slices' responses), each interval
through its own transmission.  The image is that of the whole flight's drift response.
``folded`` needs the tracked source's single set of columns and is refused here.

The counts: in each slice (default 16 slices of 15 min, each folded into mask-angle bins of
the 60 s rotation) and each energy channel, Poisson draws from the exact expected counts: the
source through the slice's mean transmission (at every node energy) plus the background of
:class:`rotmod.spectral.background.BalloonBackground` (CXB through the air, atmospheric
continuum, 511 keV line, at the slice's mean altitude profile; the mask's mean opacity) and a
detector-internal continuum, with injected scales (``TRUE_SCALES``: the published model's
level is uncertain).  Each realisation is

* **imaged**: the flight's folded counts in 150-500 keV reconstructed by MLEM with the
  background fitted per detector on a 16 x 16 deg grid; the brightest pixel must be the
  source's;
* **fitted** with :func:`rotmod.sources.spectra.fit_spectra`, forward-folded, Poisson, every
  slice's transmission modelled, in any of these ways (``--fits``):

  - ``template``: the background as four templates in time and energy (CXB, continuum, line,
    internal) whose scales are fitted (``background_free="component"``);
  - ``constant``: the same four templates held constant in time (each its flight mean), the
    scales fitted -- the background's level and spectrum free, its time dependence ignored;
  - ``levels``: a constant free level per detector and channel (the fit as it was), on the
    same slices;
  - ``folded``: the fit as it was on the flight's folded counts (slices summed), the source
    through the flight's mean transmission (every mask-angle bin samples the whole flight
    alike, to first order: with a trend inside a slice, a bin is seen at a fixed phase of
    the turn), but the levels leave only the modulation to measure the source;
  - ``shape``: the templates' sum at their nominal scales (1) as the shape in time only, with
    a free scale per detector and channel (``background_free="level"`` with a template): the
    shape in energy and across detectors is not trusted, but the components' mix sets the
    time shape in each channel, and the nominal mix is not the injected one;
  - ``shape_true``: the same with the injected sum (``TRUE_SCALES``) as the template: the
    exact time shape;
  - ``template_tilt``, ``shape_tilt`` and ``shape_true_tilt``: ``template``, ``shape`` and
    ``shape_true`` with a wrong-shaped continuum template -- tilted by
    ``(E_c / 300 keV)^-tilt`` in channel energy (its index steeper by ``--tilt``, default
    0.1) in the fitted template but not in the injected counts.

Results: the fitted index and K against the truth (mean pull = bias in units of the error,
coverage of the 1-sigma errors), the background scales, and each fit's time; an Asimov fit
(the expected counts as data: the bias without noise) of each, and of ``template_tilt`` at
smaller tilts (``--asimov-tilts``).

    nice -n 10 env OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 PYTHONPATH=src \\
        python benchmarks/flight_4h.py --n 30 --out benchmarks/results/flight_4h.json

``--merge a.json b.json`` summarises several runs together; it refuses runs of different
setups or of the same seed (the same draws twice).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
from astropy.coordinates import SkyCoord, angular_separation

from rotmod import Instrument
from rotmod.energy import EnergyResolution
from rotmod.geometry import DetectorArray, Mask
from rotmod.materials import Material
from rotmod.reconstruction import reconstruct
from rotmod.response import build_response
from rotmod.response.drift import drift_response
from rotmod.sky import Attitude, CelestialGrid, SkyGrid
from rotmod.sources.spectra import (
    SpectralColumns,
    expected_counts,
    fit_spectra,
    spectral_columns,
)
from rotmod.spectral import PowerLaw
from rotmod.spectral.atmosphere import Atmosphere
from rotmod.spectral.background import BalloonBackground, internal_rates
from rotmod.spectral.detector import tabulate_response

HOURS = 4.0
LATITUDE, DECLINATION = 34.47, 20.0
TRUTH = PowerLaw(5e-3, -2.0)                     # K (cm^-2 s^-1 keV^-1 at 100 keV), index
START = PowerLaw(1e-2, -1.6)
#: Injected background scales (the model's own level is uncertain: docs/background.md).
TRUE_SCALES = {"cxb": 1.0, "continuum": 1.2, "line": 0.8, "internal": 1.0}
#: Detector-internal background, counts s^-1 keV^-1 per detector in measured energy.
INTERNAL = PowerLaw(0.1, -1.0)
FITS = ("template", "constant", "levels", "folded", "shape", "shape_true", "template_tilt",
        "shape_tilt", "shape_true_tilt")
#: The arguments that make the expected counts: runs merged must agree on them.
SETUP_ARGS = ("slices", "bins", "rings", "nodes", "channels", "photons", "pointing", "step")
#: Zenith-pointed flight: the source's right ascension (any: it transits at mid-flight) and
#: its declination's offset north of the zenith (its smallest angle from the axis, deg).
ZENITH_RA, ZENITH_OFFSET = 180.0, 3.0
#: Sidereal rate of the hour angle (deg per hour).
SIDEREAL = 15.041
#: The Poisson draws' seed of runs made before --seed was an argument (then fixed).
OLD_SEED = 2026


def altitude(t_h: np.ndarray) -> np.ndarray:
    """Balloon altitude (km) at ``t_h`` hours: 38 km with a dip to 32 km at mid-flight."""
    return 38.0 - 3.0 * (1.0 - np.cos(2.0 * np.pi * t_h / HOURS))


def zenith(t_h: np.ndarray) -> np.ndarray:
    """The source's zenith angle (deg) from hour angle -1 h to +3 h (declination 20 deg)."""
    ha = np.radians(15.0 * (t_h - 1.0))
    phi, dec = np.radians(LATITUDE), np.radians(DECLINATION)
    return np.degrees(np.arccos(np.sin(phi) * np.sin(dec)
                                + np.cos(phi) * np.cos(dec) * np.cos(ha)))


def zenith_flight(inst: Instrument, args: argparse.Namespace, nodes: np.ndarray, dr,
                  atm: Atmosphere) -> dict:
    """A zenith-pointed flight: the attitude every ``args.step`` s, each slice's drift
    response, the source's spectral columns per slice (each interval through its own
    transmission), the whole flight's drift response for the image, and the source's
    per-slice mean zenith angle."""
    n_k = round(HOURS * 3600.0 / args.step)
    if n_k % args.slices:
        raise SystemExit(f"--step: {args.step:g} s does not cut the flight into "
                         f"{args.slices} slices of whole intervals")
    t = (np.arange(n_k) + 0.5) * args.step                   # interval mid-times (s)
    lst = ZENITH_RA + SIDEREAL * (t / 3600.0 - HOURS / 2.0)
    atts = [Attitude(float(a), LATITUDE, roll=0.0) for a in lst]
    src = SkyCoord([ZENITH_RA], [LATITUDE + ZENITH_OFFSET], unit="deg")
    theta = np.array([float(a.to_instrument(src)[0].to_value("deg")[0]) for a in atts])
    # Each interval's transmission: the source's zenith angle is its angle from the axis.
    trans = atm.transmission(nodes[None, :], theta[:, None], altitude(t / 3600.0)[:, None])
    intervals = [(float(m - args.step / 2), float(m + args.step / 2), a)
                 for m, a in zip(t, atts, strict=True)]
    grid = CelestialGrid.around(src[0], (15, 15), 1.0, atts[n_k // 2])
    per = n_k // args.slices
    slices = [drift_response(inst, grid, args.bins, intervals[i * per:(i + 1) * per],
                             energy=300.0) for i in range(args.slices)]
    cols = spectral_columns(slices, src, dr, interval_transmission=trans[:, None, :])
    at = int(np.argmin(grid.sky_coords().separation(src[0]).deg))
    return {"cols": cols, "grid": grid, "source_pixel": at,
            "resp": drift_response(inst, grid, args.bins, intervals, energy=300.0),
            "zenith": theta.reshape(args.slices, per).mean(axis=1)}


def setup(args: argparse.Namespace) -> dict:
    """The instrument, its energy-resolved columns with the per-slice transmission (or, for
    a zenith-pointed flight, per-slice columns), the background templates per slice and the
    imaging response."""
    hexa = DetectorArray.hexagonal(5.0, rings=args.rings)
    det = DetectorArray(hexa.positions, 5.0, thickness=5.0,
                        material=Material("NaI", density=3.67))
    mask = Mask(3.0, 3.0, 3.0, 100.0)
    inst = Instrument(mask, det, rotation_period=60.0)
    grid = SkyGrid.square(16.0, 1.0)
    src_xy = (4.5, 2.5)                           # a pixel centre
    th, ph = grid.from_tangent(np.array([src_xy[0]]), np.array([src_xy[1]]))
    pos = (float(th[0].to_value("deg")), float(ph[0].to_value("deg")))
    nodes = np.unique(np.r_[np.geomspace(60.0, 3000.0, args.nodes), 511.0])
    channels = np.geomspace(50.0, 2500.0, args.channels + 1)
    dr = tabulate_response(det, nodes, [0.0, 5.0, 10.0, 20.0, 40.0, 60.0, 75.0, 85.0, 89.0],
                           channels, resolution=EnergyResolution.nai(),
                           n_photons=args.photons, seed=1)
    # The flight on a 1 min track; each slice's transmission and background are the means
    # over its minutes (the counts are linear in both, and every slice holds whole turns).
    n_s = args.slices
    per = round(HOURS * 60 / n_s)                     # minutes per slice
    t_h = (np.arange(n_s * per) + 0.5) / 60.0
    h, z = altitude(t_h), zenith(t_h)
    atm = Atmosphere.from_msis()
    if args.pointing == "zenith":
        flight = zenith_flight(inst, args, nodes, dr, atm)
    else:
        trans = atm.transmission(nodes[None, :], z[:, None], h[:, None])      # (min, n_e)
        trans = trans.reshape(n_s, per, -1).mean(axis=1)[:, None, :]          # (n_s, 1, n_e)
        resp = build_response(inst, grid, args.bins, energy=300.0)
        flight = {"cols": spectral_columns(resp, ([pos[0]], [pos[1]]), dr, transmission=trans),
                  "grid": grid, "source_pixel": _pixel_at(grid, src_xy),
                  "resp": resp, "zenith": z.reshape(n_s, per).mean(axis=1)}
    bg = BalloonBackground(atm, mask=mask)
    comp = bg.flight_components(dr, det, h, step=0.1)
    tmpl = {k: v.reshape(n_s, per, -1).mean(axis=1) for k, v in comp.items()}
    tmpl["internal"] = np.broadcast_to(internal_rates(INTERNAL, channels), (n_s, channels.size - 1))
    slice_s = per * 60.0
    expo = np.full((n_s, args.bins), slice_s / args.bins)
    return {"inst": inst, **flight, "templates": tmpl, "exposure": expo, "channels": channels,
            "altitude": h.reshape(n_s, per).mean(axis=1),
            "depth": atm.column_depth(h, 0.0).reshape(n_s, per).mean(axis=1)}


def _pixel_at(grid: SkyGrid, xy: tuple[float, float]) -> int:
    """The index of the pixel centred at tangent-plane ``xy`` (deg)."""
    xc, yc = grid.pixel_centers()
    return int(np.flatnonzero(np.isclose(xc, xy[0]) & np.isclose(yc, xy[1]))[0])


def tilted(tmpl: dict, channels: np.ndarray, tilt: float) -> dict:
    """The templates with the continuum's index off by ``tilt``: times ``(E_c / 300
    keV)^-tilt`` at each channel's geometric centre ``E_c`` (a wrong-shaped template)."""
    e_c = np.sqrt(channels[:-1] * channels[1:])
    return {k: v * (e_c / 300.0) ** -tilt if k == "continuum" else v for k, v in tmpl.items()}


def image(s: dict, y: np.ndarray) -> tuple[float, float]:
    """The flight's image in 150-500 keV (folded counts summed over the slices; MLEM, the
    background fitted per detector): the distance (deg) from the source to the brightest
    pixel's centre, and the source pixel's value over the brightest other pixel's."""
    ch = s["channels"]
    band = (ch[:-1] >= 150.0) & (ch[1:] <= 500.0)
    counts = y[..., band].sum(axis=(0, 3))
    expo = s["exposure"].sum(axis=0)
    res = reconstruct(s["resp"], counts, "mlem", exposure=expo, fit_background=True)
    img = np.asarray(res.image).ravel()
    at = s["source_pixel"]
    contrast = float(img[at] / np.max(np.delete(img, at)))
    # Any grid's pixel directions (a celestial grid has no tangent-plane pixel centres for
    # angular_distance), separated as angular_distance does (Vincenty: no loss at small
    # angles; latitude is 90 deg minus the zenith angle).
    th, ph = (v.to_value("rad") for v in s["grid"].directions())
    k = int(np.argmax(img))
    sep = angular_separation(ph[k], np.pi / 2 - th[k], ph[at], np.pi / 2 - th[at])
    return float(np.degrees(sep)), contrast


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=30, help="realisations")
    ap.add_argument("--slices", type=int, default=16, help="time slices over the 4 h")
    ap.add_argument("--bins", type=int, default=30, help="mask-angle bins per turn")
    ap.add_argument("--rings", type=int, default=2, help="hexagonal rings of detectors")
    ap.add_argument("--nodes", type=int, default=48, help="true-energy nodes")
    ap.add_argument("--channels", type=int, default=24, help="energy channels")
    ap.add_argument("--photons", type=int, default=2000, help="detector MC photons per node")
    ap.add_argument("--fits", default="template,constant,levels,folded",
                    help="comma-separated fits to run: " + ", ".join(FITS))
    ap.add_argument("--tilt", type=float, default=0.1,
                    help="the wrong continuum template's index error (the *_tilt fits)")
    ap.add_argument("--asimov-tilts", default="",
                    help="comma-separated smaller tilts of template_tilt's Asimov fit")
    ap.add_argument("--seed", type=int, default=2026, help="seed of the Poisson draws")
    ap.add_argument("--pointing", choices=("track", "zenith"), default="track",
                    help="the gondola tracks the source, or points at the zenith (the sky "
                         "drifts through the field)")
    ap.add_argument("--step", type=float, default=60.0,
                    help="with --pointing zenith: the attitude's step (s)")
    ap.add_argument("--no-image", action="store_true", help="skip the images")
    ap.add_argument("--out", default=None, help="JSON file for the results")
    ap.add_argument("--merge", nargs="+", default=None,
                    help="only summarise these runs' JSON files together")
    args = ap.parse_args()
    if args.merge:
        merge(args.merge)
        return
    if args.pointing == "zenith" and "folded" in args.fits.split(","):
        raise SystemExit("--fits: 'folded' takes the tracked source's one set of columns; "
                         "with --pointing zenith each slice has its own (drop 'folded')")
    t0 = time.time()
    s = setup(args)
    t_setup = time.time() - t0
    cols, expo, tmpl = s["cols"], s["exposure"], s["templates"]
    names = list(tmpl)
    truth_bkg = sum(TRUE_SCALES[k] * tmpl[k] for k in names)
    mu = expected_counts(cols, expo, [TRUTH], background=truth_bkg)
    mu_src = expected_counts(cols, expo, [TRUTH])
    flat = {k: np.broadcast_to(v.mean(axis=0), v.shape) for k, v in tmpl.items()}
    wrong = tilted(tmpl, s["channels"], args.tilt)
    fits = {"template": {"background": tmpl, "background_free": "component"},
            "constant": {"background": flat, "background_free": "component"},
            "levels": {}, "folded": {},
            "shape": {"background": sum(tmpl.values()), "background_free": "level"},
            "shape_true": {"background": truth_bkg, "background_free": "level"},
            "template_tilt": {"background": wrong, "background_free": "component"},
            "shape_tilt": {"background": sum(wrong.values()), "background_free": "level"},
            "shape_true_tilt": {"background": sum(TRUE_SCALES[k] * wrong[k] for k in names),
                                "background_free": "level"}}
    unknown = set(args.fits.split(",")) - set(fits)
    if unknown:
        raise SystemExit(f"--fits: unknown {sorted(unknown)}; choose from {', '.join(FITS)}")
    fits = {k: fits[k] for k in args.fits.split(",")}
    # The flight's folded counts (slices summed): the sources through the flight's mean
    # transmission (equal slices), one interval, a constant level per detector and channel.
    folded = None if "folded" not in fits else SpectralColumns(
        cols.columns * cols.transmission.mean(axis=0)[:, None, :, None, None],
        cols.redistribution, cols.energies, cols.channel_edges, cols.theta)

    def data(name: str, y: np.ndarray) -> tuple:
        if name == "folded":
            return folded, y.sum(axis=0), expo.sum(axis=0)
        return cols, y, expo
    print(f"setup {t_setup:.1f} s; {cols.shape[1]} detectors, {args.slices} slices x "
          f"{args.bins} bins x {cols.shape[-1]} channels; source {mu_src.sum():.3g} counts, "
          f"background {mu.sum() - mu_src.sum():.3g}")
    print("slice altitude (km) " + " ".join(f"{v:.1f}" for v in s["altitude"]))
    print("slice depth (g/cm2) " + " ".join(f"{v:.2f}" for v in s["depth"]))
    print("slice zenith (deg)  " + " ".join(f"{v:.1f}" for v in s["zenith"]))
    rate_t = truth_bkg.sum(axis=-1)
    print("background counts/s per detector per slice " + " ".join(f"{v:.0f}" for v in rate_t))
    for k, v in tmpl.items():
        print(f"  {k:>9} x {TRUE_SCALES[k]}: " + " ".join(f"{x:.1f}" for x in
                                                         TRUE_SCALES[k] * v.sum(axis=-1)))
    lo = truth_bkg[:, :6].sum(axis=-1)
    print("  50-95 keV (6 channels): " + " ".join(f"{x:.1f}" for x in lo))
    report: dict = {"args": vars(args), "setup_s": t_setup, "load": os.getloadavg(),
                    "source_counts": float(mu_src.sum()),
                    "background_counts": float(mu.sum() - mu_src.sum()),
                    "altitude": s["altitude"].tolist(), "depth": s["depth"].tolist(),
                    "zenith": s["zenith"].tolist(), "true_scales": TRUE_SCALES,
                    "seed": args.seed, "realisations": []}
    # Asimov: each fit on the expected counts (its bias without noise).
    asimov = {}
    comp = {name for name, kw in fits.items() if kw.get("background_free") == "component"}
    for name, kw in fits.items():
        t1 = time.time()
        f = fit_spectra(*data(name, mu), [START], **kw)
        asimov[name] = {"K": f.models[0].K, "index": f.models[0].index,
                        "K_err": f.errors[0]["K"], "index_err": f.errors[0]["index"],
                        "scales": f.scales.tolist() if name in comp else None,
                        "scale_errors": f.scale_errors.tolist() if name in comp else None,
                        "loglike": f.loglike, "time_s": time.time() - t1}
        a = asimov[name]
        print(f"Asimov {name:>9}: index {a['index']:.4f} +- {a['index_err']:.4f}, "
              f"K {a['K']:.4e} +- {a['K_err']:.2e}, -2 lnL {-2 * a['loglike']:.1f}, "
              + (" ".join(f"{k} {v:.4f}+-{e:.4f}" for k, v, e in
                          zip(names, a["scales"], a["scale_errors"], strict=True))
                 if a["scales"] else "") + f" ({a['time_s']:.1f} s)")
    for tilt in (float(v) for v in args.asimov_tilts.split(",") if v):
        t1 = time.time()
        kw = {"background": tilted(tmpl, s["channels"], tilt), "background_free": "component"}
        f = fit_spectra(cols, mu, expo, [START], **kw)
        asimov[f"template_tilt {tilt:g}"] = {
            "K": f.models[0].K, "index": f.models[0].index, "K_err": f.errors[0]["K"],
            "index_err": f.errors[0]["index"], "scales": f.scales.tolist(),
            "scale_errors": f.scale_errors.tolist(), "loglike": f.loglike,
            "time_s": time.time() - t1}
        print(f"Asimov template_tilt {tilt:g}: index {f.models[0].index:.4f} +- "
              f"{f.errors[0]['index']:.4f}, K {f.models[0].K:.4e}, -2 lnL "
              f"{-2 * f.loglike:.1f}, scales " + " ".join(f"{v:.4f}" for v in f.scales))
    report["asimov"] = asimov
    rng = np.random.default_rng(args.seed)
    for r in range(args.n):
        y = rng.poisson(mu)
        row: dict = {}
        t1 = time.time()
        if not args.no_image:
            row["image_offset_deg"], row["image_contrast"] = image(s, y)
            row["image_s"] = time.time() - t1
        for name, kw in fits.items():
            t1 = time.time()
            f = fit_spectra(*data(name, y), [START], **kw)
            row[name] = {"K": f.models[0].K, "index": f.models[0].index,
                         "K_err": f.errors[0]["K"], "index_err": f.errors[0]["index"],
                         "converged": f.converged, "loglike": f.loglike,
                         "time_s": time.time() - t1}
            if name in comp:
                row[name]["scales"] = f.scales.tolist()
                row[name]["scale_errors"] = f.scale_errors.tolist()
        report["realisations"].append(row)
        if args.out:                      # kept after each realisation: a run cut short counts
            with open(args.out, "w") as f:
                json.dump(report, f, indent=1)
        print(f"{r:3d} " + ("" if args.no_image else f"image {row['image_offset_deg']:.2f} "
              f"deg (x{row['image_contrast']:.2f}); ") + "; ".join(
            f"{n} {row[n]['index']:.3f}+-{row[n]['index_err']:.3f} ({row[n]['time_s']:.1f} s)"
            for n in fits), flush=True)
    summarise(report, list(fits), names)
    report["load_end"] = os.getloadavg()
    print(f"load average {report['load']} -> {report['load_end']}")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(report, f, indent=1)


def summarise(report: dict, fits: list[str], names: list[str]) -> None:
    rows = report["realisations"]
    if not rows:
        return
    truth = {"K": TRUTH.K, "index": TRUTH.index}
    summary: dict = {}
    report["summary"] = summary
    if all("image_offset_deg" in r for r in rows):
        image_summary(report, rows)
    print(f"{'fit':>13} {'param':>6} {'mean':>11} {'median err':>11} {'mean pull':>10} "
          f"{'pull std':>9} {'in 1 sigma':>11} {'in 1.645':>11} {'median s':>9}")
    for name in fits:
        fit_summary(summary, rows, name, names, truth)


def image_summary(report: dict, rows: list) -> None:
    n = len(rows)
    off = np.array([r["image_offset_deg"] for r in rows])
    con = np.array([r["image_contrast"] for r in rows])
    print(f"\nimage: brightest pixel on the source's in {np.sum(off < 0.5)}/{n} "
          f"(median offset {np.median(off):.2f} deg; source pixel / brightest other: median "
          f"{np.median(con):.2f}, min {con.min():.2f})")
    report["image"] = {"on_pixel": int(np.sum(off < 0.5)), "n": n,
                       "median_offset_deg": float(np.median(off)),
                       "median_contrast": float(np.median(con)), "min_contrast": float(con.min())}


def fit_summary(summary: dict, rows: list, name: str, names: list[str], truth: dict) -> None:
    """Bias (mean pull), pull width and coverage of one fit's index and K, and its scales."""
    n = len(rows)
    summary[name] = {}
    for p in ("index", "K"):
        v = np.array([r[name][p] for r in rows])
        e = np.array([r[name][f"{p}_err"] for r in rows])
        pull = (v - truth[p]) / e
        t = np.median([r[name]["time_s"] for r in rows])
        k1, k9 = int(np.sum(np.abs(pull) < 1)), int(np.sum(np.abs(pull) < 1.645))
        summary[name][p] = {"mean": float(v.mean()), "median_err": float(np.median(e)),
                            "mean_pull": float(pull.mean()), "pull_std": float(pull.std(ddof=1)),
                            "in1": k1, "in90": k9, "n": n, "median_time_s": float(t)}
        print(f"{name:>13} {p:>6} {v.mean():>11.4g} {np.median(e):>11.3g} "
              f"{pull.mean():>10.2f} {pull.std(ddof=1):>9.2f} {k1:>5d}/{n:<5d} "
              f"{k9:>5d}/{n:<5d} {t:>9.1f}")
    if "scales" in rows[0][name]:
        sc = np.array([r[name]["scales"] for r in rows])
        se = np.array([r[name]["scale_errors"] for r in rows])
        pull = (sc - np.array([TRUE_SCALES[k] for k in names])) / se
        summary[name]["scales"] = {
            k: {"mean": float(sc[:, j].mean()), "median_err": float(np.median(se[:, j])),
                "mean_pull": float(pull[:, j].mean()), "pull_std": float(pull[:, j].std(ddof=1)),
                "in1": int(np.sum(np.abs(pull[:, j]) < 1))}
            for j, k in enumerate(names)}
        print(f"{'':>13} scales " + "; ".join(
            f"{k} {sc[:, j].mean():.4f} (err {np.median(se[:, j]):.4f}, pull "
            f"{pull[:, j].mean():+.2f} +- {pull[:, j].std(ddof=1):.2f}, in 1 sigma "
            f"{np.sum(np.abs(pull[:, j]) < 1)}/{n})" for j, k in enumerate(names)))


def merge(paths: list[str]) -> None:
    """Summarise the realisations of several runs' JSON files together (the fits they all
    hold); refuse runs whose expected counts differ (``SETUP_ARGS``), whose seeds repeat (the
    same draws counted twice) or whose wrong templates differ (``tilt``, for the ``*_tilt``
    fits)."""
    reports = []
    for p in paths:
        with open(p) as f:
            reports.append(json.load(f))
    args = [rep["args"] for rep in reports]
    def setting(a: dict, k: str) -> object:
        """A run's value of ``k``; runs made before --pointing existed tracked their source,
        and a tracked source's --step is unused."""
        if k == "step" and a.get("pointing", "track") == "track":
            return None
        return a.get(k, "track" if k == "pointing" else None)

    for k in SETUP_ARGS:
        if len({setting(a, k) for a in args}) > 1:
            each = ", ".join(f"{p}: {setting(a, k)}" for p, a in zip(paths, args, strict=True))
            raise SystemExit(f"--merge: the runs differ in --{k} ({each})")
    seeds = [rep.get("seed", a.get("seed", OLD_SEED)) for rep, a in zip(reports, args, strict=True)]
    if len(set(seeds)) < len(seeds):
        raise SystemExit(f"--merge: two runs share a seed ({', '.join(map(str, seeds))}): "
                         "their realisations are the same draws")
    rows = [r for rep in reports for r in rep["realisations"]]
    fits = [f for f in FITS if all(f in r for r in rows)]
    if any(f.endswith("_tilt") for f in fits) and len({a.get("tilt") for a in args}) > 1:
        raise SystemExit("--merge: the runs' wrong templates differ in --tilt")
    print(f"{len(rows)} realisations of {len(paths)} runs (seeds {', '.join(map(str, seeds))})")
    report = {"realisations": rows}
    summarise(report, fits, list(TRUE_SCALES))


if __name__ == "__main__":
    main()
