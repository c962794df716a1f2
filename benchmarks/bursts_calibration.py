"""Calibration of the burst chain (issue 22): inject, search, analyse, compare with the truth.

Survey instrument (37 detectors, b/L = 1.72 deg, 4 s turn), 300 keV, background 1.5
counts/s/detector, fixed attitude ``Attitude(30, 40, 10)``; 300 s of data with a burst of 1-3
Norris pulses starting at t = 100 s.  Truth: theta uniform in cos(theta) over 0-60 deg, phi
uniform; rise log-uniform 0.1-1 s, decay log-uniform 0.3-15 s, later pulses starting
uniformly 0-20 s after the first with peaks 0.3-1 of the first's; the first pulse's peak
(photons/s on one unobstructed detector face) log-uniform 2-200.  Each burst is searched
(:func:`rotmod.bursts.search.search`); the candidate overlapping the injected burst is
analysed (:func:`rotmod.bursts.analysis.analyse_burst`, searched cone 65 deg, one shared
response cache); a missed burst is recorded and not analysed.  The first ``--no-lc-subset``
detected bursts are analysed again with ``light_curve=False``.  ``--shape gauss-exp``
injects pulses of a shape the model does not have (a Gaussian rise, an exponential decay;
the same draws), a check that the coverage does not rest on the model's pulse family.

Printed (and written to ``benchmarks/results/bursts_calibration.txt``): coverage of the 90 %
and 68 % regions (all, and without the bursts where a mirror mode within delta TS < 9 was
nearer the truth than the best position), r90/(b/L) against sqrt(TS) with a power-law fit
beside the coded-mask law quoted in the issue, the light-curve-weighted against the constant
localisation, T90 against the truth, and the analysis latency.

Each burst also records the light curve's dispersion (the factor its regions' TS was
divided by, :attr:`rotmod.bursts.BurstPosition.dispersion`), the fitted pulses, and whether
the truth is in the regions without that factor (tempered back), so one run gives the
coverage with and without it.  ``--report --compare OLD.json ...`` sets an earlier run of
the same draws beside this one, burst by burst.

Results are appended to the JSON after every burst; ``--resume`` skips the bursts done.

    python benchmarks/bursts_calibration.py --n 3 --out /tmp/bcal3.json   # a check
    NUMBA_NUM_THREADS=1 python benchmarks/bursts_calibration.py --n 100    # the saved run
    python benchmarks/bursts_calibration.py --report                       # table of a JSON
    # two shards, one core each, then one report of both:
    NUMBA_NUM_THREADS=1 python benchmarks/bursts_calibration.py --shard 0/2 --out a.json &
    NUMBA_NUM_THREADS=1 python benchmarks/bursts_calibration.py --shard 1/2 --out b.json
    python benchmarks/bursts_calibration.py --out a.json --report b.json
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import platform
import sys
import time
import traceback
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_OUT = ROOT / "benchmarks" / "results" / "bursts_calibration.json"

SEED = 20261126
T_START, T_STOP, T_BURST = 0.0, 300.0, 100.0
TRUTH_WINDOW = (90.0, 220.0)
ENERGY = 300.0
BACKGROUND = 1.5
RADIUS = 65.0
THETA_MAX = 60.0
AMP_RANGE = (3.0, 100.0)
RISE_RANGE = (0.1, 1.0)
DECAY_RANGE = (0.3, 15.0)
PULSE_SPREAD = 20.0
ALT_DTS = 9.0


def setup():
    from rotmod import Instrument
    from rotmod.geometry import DetectorArray, Mask
    from rotmod.sky import Attitude
    inst = Instrument(Mask(3, 3, 3, 100), DetectorArray.hexagonal(5, rings=3), rotation_period=4.0)
    return inst, Attitude(30.0, 40.0, 10.0)


def draw_truth(seed: int, i: int) -> dict:
    rng = np.random.default_rng([seed, i])
    cos_t = rng.uniform(math.cos(math.radians(THETA_MAX)), 1.0)
    theta = math.degrees(math.acos(cos_t))
    phi = rng.uniform(0.0, 360.0)
    amp = math.exp(rng.uniform(*np.log(AMP_RANGE)))
    n_p = int(rng.integers(1, 4))
    pulses = []
    for k in range(n_p):
        start = T_BURST if k == 0 else T_BURST + rng.uniform(0.0, PULSE_SPREAD)
        rise = math.exp(rng.uniform(*np.log(RISE_RANGE)))
        decay = math.exp(rng.uniform(*np.log(DECAY_RANGE)))
        a = amp if k == 0 else amp * rng.uniform(0.3, 1.0)
        pulses.append([start, rise, decay, a])
    return {"theta": theta, "phi": phi, "amplitude": amp, "pulses": pulses,
            "sim_seed": int(rng.integers(2**31))}


#: The pulses' shape: "norris" (the model's own family) or "gauss-exp" (a check of a shape
#: the model does not have: a Gaussian rise of width ``rise`` to the peak at
#: ``start + 3 rise``, then an exponential decay of ``decay``), set by ``--shape``.
SHAPE = "norris"


def _gauss_exp(t, start, rise, decay, amp):
    dt = t - (start + 3.0 * rise)
    return amp * np.where(dt < 0.0, np.exp(-0.5 * (dt / rise) ** 2),
                          np.exp(-np.maximum(dt, 0.0) / decay))


def light_curve(pulses):
    from rotmod.bursts.measure import norris_pulse
    shape = {"norris": norris_pulse, "gauss-exp": _gauss_exp}[SHAPE]

    def lc(t):
        t = np.asarray(t, dtype=float)
        out = np.zeros_like(t)
        for s, r, d, a in pulses:
            out = out + shape(t, s, r, d, a)
        return out
    return lc


def _sep(a, b) -> float:
    return float(a.separation(b).deg)


def run_one(i: int, seed: int, inst, att, cache: dict, do_nolc: bool) -> dict:
    from rotmod.bursts.analysis import analyse_burst
    from rotmod.bursts.inject import simulate_burst
    from rotmod.bursts.measure import true_durations
    from rotmod.bursts.search import search

    tr = draw_truth(seed, i)
    lc = light_curve(tr["pulses"])
    true = true_durations(lc, *TRUTH_WINDOW)
    rec: dict = {"index": i, "truth": tr, "true_t90": true.t90, "true_t90_start": true.t90_start,
                 "true_t50": true.t50}
    pos = att.to_sky(tr["theta"], tr["phi"])
    ev = simulate_burst(inst, pos, lc, t_start=T_START, t_stop=T_STOP, background=BACKGROUND,
                        energy=ENERGY, attitude=att, seed=tr["sim_seed"])
    res = search(ev)
    b0 = T_BURST
    b1 = true.t90_start + true.t90 + 1.0
    over = [c for c in res.candidates if c.interval[1] > b0 - 1.0 and c.interval[0] < b1]
    rec["n_candidates"] = len(res.candidates)
    rec["n_false_candidates"] = len(res.candidates) - len(over)
    if not over:
        rec["detected"] = False
        return rec
    cand = max(over, key=lambda c: c.significance)
    rec.update(detected=True, trigger={"time": cand.time, "timescale": cand.timescale,
                                       "significance": cand.significance})
    t = time.perf_counter()
    load0 = os.getloadavg()[0]
    try:
        burst = analyse_burst(ev, cand, energy=ENERGY, radius=RADIUS, light_curve=True,
                              cache=cache)
    except Exception as exc:  # recorded, not fatal
        rec["error"] = f"{type(exc).__name__}: {exc}"
        rec["traceback"] = traceback.format_exc()
        rec["analyse_time"] = time.perf_counter() - t
        return rec
    rec["analyse_time"] = time.perf_counter() - t
    rec["loadavg"] = [load0, os.getloadavg()[0]]
    bp = burst.position
    best_sep = _sep(bp.position, pos)
    alts = [(float(dts), _sep(c, pos), _sep(c, bp.position)) for c, dts in bp.alternatives]
    close = [a for a in alts if a[0] < ALT_DTS]
    rec.update(
        sqrt_ts=bp.sqrt_ts, fit_theta=bp.theta, fit_phi=bp.phi, separation=best_sep,
        r90=bp.region.radius(0.9), r68=bp.region.radius(0.68),
        contains90=bp.contains(pos, 0.9), contains68=bp.contains(pos, 0.68),
        best_mode_contains90=bp.region.contains(pos, 0.9),
        posterior=bp.posterior.describe(),
        alternatives=alts, alt_close=bool(close),
        mirror_won=bool(any(a[1] < best_sep for a in close)),
        interval=list(burst.interval), t90=burst.durations.t90,
        t90_err=burst.durations.t90_err, fluence=burst.fluence,
        fluence_err=burst.fluence_err,
    )
    # The light curve's misfit and what it did to the region: the dispersion the TS
    # surfaces were divided by, and the regions undone to the likelihood's own (tempered
    # back by its inverse) for the coverage without it, in the same run.
    from rotmod.bursts.posterior import Posterior, tempered
    raw = Posterior(tuple(tempered(q, 1.0 / bp.dispersion) for q in bp.posterior.squares))
    rec.update(dispersion=bp.dispersion, misfit=bp.misfit,
               raw_contains90=raw.contains(pos, 0.9), raw_contains68=raw.contains(pos, 0.68),
               raw_r90=tempered(bp.region, 1.0 / bp.dispersion).radius(0.9),
               pulse_family=None if bp.pulses is None else bp.pulses.family.name,
               pulses=None if bp.pulses is None else bp.pulses.pulses.tolist())
    rec.update(truth_diagnostic(burst, pos))
    # Where the truth stands in the search's score map: the rank of its pixel (0 = the map's
    # best) and its score below the best.  ``bp.score`` is the map the search ended with:
    # since eea3768 the second map (weighted by the pulses seen from the first's likeliest
    # peak), before it the only one.
    sc = bp.score
    k = int(np.argmin(sc.grid.sky_coords().separation(pos).deg))
    s_map = np.nan_to_num(sc.score, nan=-np.inf)
    rec.update(score_rank=int(np.sum(s_map > s_map[k])),
               score_ratio=float(s_map[k] / np.max(s_map)))
    if do_nolc:
        t = time.perf_counter()
        try:
            b2 = analyse_burst(ev, cand, energy=ENERGY, radius=RADIUS, light_curve=False,
                               cache=cache)
            p2 = b2.position
            s2 = _sep(p2.position, pos)
            alts2 = [(float(d), _sep(c, pos)) for c, d in p2.alternatives]
            rec["nolc"] = {
                "separation": s2, "r90": p2.region.radius(0.9), "r68": p2.region.radius(0.68),
                "contains90": p2.contains(pos, 0.9),
                "contains68": p2.contains(pos, 0.68), "sqrt_ts": p2.sqrt_ts,
                "mirror_won": bool(any(d < ALT_DTS and s < s2 for d, s in alts2)),
                "fit_theta": p2.theta, "fit_phi": p2.phi,
                "time": time.perf_counter() - t}
        except Exception as exc:
            rec["nolc"] = {"error": f"{type(exc).__name__}: {exc}"}
    return rec


def truth_diagnostic(burst, truth) -> dict:
    """The TS of the best fit above the truth's (flux and background levels refitted, the
    position held at the truth, the pulses fitted as seen from there as from any start),
    in the fine fit's own bins and response: ``dts_truth < 0`` means the fit missed a
    higher maximum (at the truth); for a 2-D Wilks surface the truth is in the 90 % region
    when ``dts_truth < 4.61``."""
    from rotmod.bursts.localisation import _background_rates, burst_pulses
    from rotmod.sources.fitting import SourceFitter
    from rotmod.sources.model import PointSource, SkyModel
    try:
        bp = burst.position
        rates = _background_rates(burst.background, bp.counts)
        data = bp.counts.data(rates)
        ll_best = SourceFitter(bp.response, data).maximise(bp.fit.model)[1].loglike
        src = PointSource(truth)
        unit = bp.response.with_weight(None)
        w = burst_pulses(burst.light_curve, bp.counts, burst.background, unit, src,
                         burst_pulses(burst.light_curve, bp.counts, burst.background)
                         ).shape(bp.counts.edges)
        fitter = SourceFitter(unit.with_weight(w), data)
        ll_true = fitter.maximise(SkyModel((src,)))[1].loglike
        return {"dts_truth": float(2.0 * (ll_best - ll_true))}
    except Exception as exc:
        return {"dts_truth_error": f"{type(exc).__name__}: {exc}"}


def save(path: Path, data: dict) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)


# --------------------------------------------------------------------------- report
def binom_2sigma(k: int, n: int) -> tuple[float, float]:
    """Central 95.45 % Clopper-Pearson interval of a fraction k/n."""
    from scipy.stats import beta
    if n == 0:
        return (float("nan"), float("nan"))
    a = 1.0 - 0.9545
    lo = 0.0 if k == 0 else beta.ppf(a / 2, k, n - k + 1)
    hi = 1.0 if k == n else beta.ppf(1 - a / 2, k + 1, n - k)
    return float(lo), float(hi)


def frac_line(label: str, k: int, n: int) -> str:
    if n == 0:
        return f"  {label:<44s} 0/0"
    lo, hi = binom_2sigma(k, n)
    return f"  {label:<44s} {k:3d}/{n:<3d} = {k / n:5.3f}  (2 sigma {lo:.3f}-{hi:.3f})"


def report(data: dict) -> str:
    from rotmod.sources.fitting import geometric_scale
    inst, _ = setup()
    scale = math.degrees(geometric_scale(inst))
    recs = sorted(data["bursts"], key=lambda r: r["index"])
    cfg = data["config"]
    L = []
    L.append("Burst calibration (issue 22): inject -> search -> analyse_burst")
    L.append(f"  config: {json.dumps(cfg)}")
    L.append(f"  b/L = {scale:.3f} deg; theta uniform in cos(theta) 0-{THETA_MAX:g} deg, phi "
             f"uniform; peak amplitude log-uniform {AMP_RANGE[0]:g}-{AMP_RANGE[1]:g}; "
             f"1-3 pulses of shape {cfg.get('shape', 'norris')}")
    n_all = len(recs)
    det = [r for r in recs if r.get("detected")]
    err = [r for r in det if "error" in r]
    ok = [r for r in det if "error" not in r]
    L.append(f"  bursts done {n_all} (requested {cfg.get('n')}); detected {len(det)}; "
             f"analysis errors {len(err)}; analysed {len(ok)}")
    missed = [r for r in recs if not r.get("detected")]
    if missed:
        amps = ", ".join(f"{r['truth']['amplitude']:.1f}" for r in missed)
        L.append(f"  missed (peak amplitude): {amps}")
    nfalse = sum(r.get("n_false_candidates", 0) for r in recs)
    L.append(f"  candidates not overlapping the burst (false or split): {nfalse} in "
             f"{n_all * (T_STOP - T_START):g} s")
    for r in err:
        t = r["truth"]
        L.append(f"  ERROR #{r['index']}: {r['error']}  (theta {t['theta']:.1f} phi "
                 f"{t['phi']:.1f} amp {t['amplitude']:.2f} pulses {t['pulses']})")
    if not ok:
        return "\n".join(L)

    sq = np.array([r["sqrt_ts"] for r in ok])
    L.append(f"  sqrt TS range {sq.min():.1f}-{sq.max():.1f} (median {np.median(sq):.1f})")
    mirror = [r for r in ok if r["mirror_won"]]
    clean = [r for r in ok if not r["mirror_won"]]
    L.append("")
    L.append("Coverage of the regions (truth inside)")
    for lab, sel in (("all analysed", ok), ("excluding mirror-mode wins", clean)):
        L.append(frac_line(f"90 % region, {lab}", sum(r["contains90"] for r in sel), len(sel)))
        L.append(frac_line(f"68 % region, {lab}", sum(r["contains68"] for r in sel), len(sel)))
    infl = [r for r in ok if "dispersion" in r]
    if infl:
        disp = np.array([r["dispersion"] for r in infl])
        L.append(frac_line("90 % region without the misfit's inflation",
                           sum(r["raw_contains90"] for r in infl), len(infl)))
        L.append(frac_line("68 % region without the misfit's inflation",
                           sum(r["raw_contains68"] for r in infl), len(infl)))
        L.append(f"  light-curve dispersion (TS divided by): median {np.median(disp):.2f}, "
                 f"> 1 in {int(np.sum(disp > 1))}/{disp.size}, > 1.5 in "
                 f"{int(np.sum(disp > 1.5))}, max {disp.max():.2f}; median r90 / r90 "
                 f"without it "
                 f"{np.median([r['r90'] / r['raw_r90'] for r in infl if r['raw_r90'] > 0]):.3f}"
                 f" (raw r90 0, a region of the square's one point: "
                 f"{sum(r['raw_r90'] <= 0 for r in infl)})")
        nu = np.array([p[3:5] for r in infl if r.get("pulse_family") == "peaked"
                       for p in r["pulses"]])
        if nu.size:
            L.append(f"  fitted peakedness of {len(nu)} pulses: nu_rise median "
                     f"{np.median(nu[:, 0]):.2f} (10-90 % {np.percentile(nu[:, 0], 10):.2f}-"
                     f"{np.percentile(nu[:, 0], 90):.2f}), nu_decay median "
                     f"{np.median(nu[:, 1]):.2f} ({np.percentile(nu[:, 1], 10):.2f}-"
                     f"{np.percentile(nu[:, 1], 90):.2f})")
    old = data.get("compare")
    if old:
        both = [(r, old[str(r["index"])]) for r in ok if str(r["index"]) in old]
        L.append(f"  the same draws in the compared run ({len(both)} analysed in both):")
        L.append(frac_line("    90 %, this run", sum(r["contains90"] for r, _ in both),
                           len(both)))
        L.append(frac_line("    90 %, compared run", sum(o["contains90"] for _, o in both),
                           len(both)))
        for r, o in both:
            if r["contains90"] != o["contains90"]:
                L.append(f"    #{r['index']}: now {'in' if r['contains90'] else 'OUT'} "
                         f"(sqrtTS {r['sqrt_ts']:.1f}, sep/r90 "
                         f"{r['separation'] / r['r90']:.2f}), before "
                         f"{'in' if o['contains90'] else 'OUT'} (sqrtTS {o['sqrt_ts']:.1f}, "
                         f"sep/r90 {o['separation'] / o['r90']:.2f})")
    L.append("  by sqrt(TS) (all analysed):")
    for lo, hi in ((0, 12), (12, 20), (20, 35), (35, 1e9)):
        sel = [r for r in ok if lo <= r["sqrt_ts"] < hi]
        if sel:
            lab = f"{lo:g}-{hi:g}" if hi < 1e8 else f">= {lo:g}"
            L.append(frac_line(f"  90 %, sqrt TS {lab}", sum(r["contains90"] for r in sel),
                               len(sel)))
            L.append(frac_line(f"  68 %, sqrt TS {lab}", sum(r["contains68"] for r in sel),
                               len(sel)))
    # Short bursts (the truth's T90 under half a turn) see part of the rotation only.
    half = 0.5 * setup()[0].rotation_period
    L.append(f"  by the truth's T90 (half a turn is {half:g} s):")
    for lab, sel in ((f"T90 < {half:g} s", [r for r in ok if r["true_t90"] < half]),
                     (f"T90 >= {half:g} s", [r for r in ok if r["true_t90"] >= half])):
        for lo, hi in ((0, 20), (20, 1e9)):
            part = [r for r in sel if lo <= r["sqrt_ts"] < hi]
            tag = f"sqrt TS < {hi:g}" if lo == 0 else f"sqrt TS >= {lo:g}"
            L.append(frac_line(f"  90 %, {lab}, {tag}", sum(r["contains90"] for r in part),
                               len(part)))
    multi = [r for r in ok if len(r.get("posterior", {}).get("modes", [1])) > 1]
    L.append(frac_line("region of more than one mode", len(multi), len(ok)))
    L.append(frac_line("best-mode region alone holds the truth (90 %)",
                       sum(r.get("best_mode_contains90", False) for r in ok), len(ok)))
    ranks = np.array([r["score_rank"] for r in ok if "score_rank" in r])
    if ranks.size:
        L.append(f"  score map: the truth's pixel is the map's best in "
                 f"{int(np.sum(ranks == 0))}/{ranks.size}, within its 5 best in "
                 f"{int(np.sum(ranks < 5))}, within 50 in {int(np.sum(ranks < 50))}")
        for lo, hi in ((0, 12), (12, 1e9)):
            sel = [r for r in ok if "score_rank" in r and lo <= r["sqrt_ts"] < hi]
            if sel:
                rk = np.array([r["score_rank"] for r in sel])
                L.append(f"    sqrt TS {lo:g}-{hi:g}: best {int(np.sum(rk == 0))}/{rk.size}, "
                         f"top 5 {int(np.sum(rk < 5))}, median rank {np.median(rk):.0f}")
    L.append(frac_line("alternative mode within dTS<9 exists", sum(r["alt_close"] for r in ok),
                       len(ok)))
    L.append(frac_line("mirror mode won (truth nearer the alternative)", len(mirror), len(ok)))
    for r in mirror:
        t = r["truth"]
        near = min(a[1] for a in r["alternatives"] if a[0] < ALT_DTS)
        L.append(f"    #{r['index']}: theta {t['theta']:.1f} phi {t['phi']:.1f} sqrtTS "
                 f"{r['sqrt_ts']:.1f}, best {r['separation']:.2f} deg off, alternative "
                 f"{near:.2f} deg off")
    fails = [r for r in ok if not r["contains90"]]
    fringe = math.degrees(inst.mask.period / inst.mask.height)  # p cos^2(theta) / L at 0
    for r in fails:
        t = r["truth"]
        L.append(f"    outside 90 %: #{r['index']} theta {t['theta']:.1f} phi {t['phi']:.1f} "
                 f"amp {t['amplitude']:.1f} np {len(t['pulses'])} sqrtTS {r['sqrt_ts']:.1f} "
                 f"sep {r['separation']:.2f} r90 {r['r90']:.2f} sep/r90 "
                 f"{r['separation'] / r['r90']:.1f} sep/fringe "
                 f"{r['separation'] / (fringe * math.cos(math.radians(t['theta'])) ** 2):.2f} "
                 f"dTS(best-truth) {r.get('dts_truth', float('nan')):+.1f} dispersion "
                 f"{r.get('dispersion', float('nan')):.2f}"
                 + (" (mirror won)" if r["mirror_won"] else ""))
    dd = [r for r in ok if "dts_truth" in r]
    if dd:
        L.append(f"  TS of the best fit minus TS at the truth (fine fit's bins; 2-D Wilks: "
                 f"truth in 90 % iff < 4.61), {len(dd)} bursts:")
        L.append(frac_line("dTS < 4.61 (ideal-region coverage, 90 %)",
                           sum(r["dts_truth"] < 4.61 for r in dd), len(dd)))
        L.append(frac_line("dTS < 2.30 (ideal-region coverage, 68 %)",
                           sum(r["dts_truth"] < 2.30 for r in dd), len(dd)))
        L.append(frac_line("dTS < -1: fit missed a higher maximum (truth)",
                           sum(r["dts_truth"] < -1.0 for r in dd), len(dd)))
        miss = [r for r in dd if r["dts_truth"] < -1.0]
        for r in miss:
            t = r["truth"]
            L.append(f"    missed max: #{r['index']} theta {t['theta']:.1f} phi {t['phi']:.1f} "
                     f"amp {t['amplitude']:.2f} pulses {len(t['pulses'])} sqrtTS "
                     f"{r['sqrt_ts']:.1f} (at truth "
                     f"{math.sqrt(max(r['sqrt_ts'] ** 2 - r['dts_truth'], 0)):.1f}) "
                     f"sep {r['separation']:.2f} deg = "
                     f"{r['separation'] / (fringe * math.cos(math.radians(t['theta'])) ** 2):.2f}"
                     f" fringes")
    # Ratio separation/r90 as a calibration diagnostic (2-D Gaussian: r90 = 2.146 sigma,
    # median sep = 1.177 sigma -> median sep/r90 = 0.548).
    ratio = np.array([r["separation"] / r["r90"] for r in clean]) if clean else np.array([])
    if ratio.size:
        L.append(f"  median sep/r90 (no mirror) {np.median(ratio):.3f}  (ideal 2-D Gaussian "
                 f"0.548)")

    L.append("")
    L.append("r90 / (b/L) against sqrt(TS)  (no mirror wins; median per bin)")
    L.append(f"  {'sqrtTS bin':>12s} {'N':>4s} {'med sqrtTS':>10s} {'r90/(b/L)':>10s} "
             f"{'r68/(b/L)':>10s} {'sep/(b/L)':>10s} {'fit':>8s} {'BAT law':>8s}")
    x = np.array([r["sqrt_ts"] for r in clean])
    y = np.array([r["r90"] for r in clean]) / scale
    good = (x > 0) & (y > 0)
    if good.sum() >= 3:
        k_fit, lnA = np.polyfit(np.log(x[good]), np.log(y[good]), 1)
        A_fit, k_fit = math.exp(lnA), -k_fit
    else:
        A_fit, k_fit = float("nan"), float("nan")
    # The Swift-BAT law: 0.16 at SNR 7, 0.06 at SNR 30.
    k_bat = math.log(0.16 / 0.06) / math.log(30 / 7)
    A_bat = 0.16 * 7 ** k_bat
    edges = [0, 8, 12, 20, 35, 60, 1e9]
    for lo, hi in itertools.pairwise(edges):
        sel = [r for r in clean if lo <= r["sqrt_ts"] < hi]
        if not sel:
            continue
        s = np.median([r["sqrt_ts"] for r in sel])
        L.append(f"  {lo:>5g}-{hi if hi < 1e8 else 'inf':<6} {len(sel):4d} {s:10.1f} "
                 f"{np.median([r['r90'] for r in sel]) / scale:10.3f} "
                 f"{np.median([r['r68'] for r in sel]) / scale:10.3f} "
                 f"{np.median([r['separation'] for r in sel]) / scale:10.3f} "
                 f"{A_fit * s ** -k_fit:8.3f} {A_bat * s ** -k_bat:8.3f}")
    L.append(f"  fit r90/(b/L) = {A_fit:.2f} * SNR^-{k_fit:.2f}   (BAT law quoted: "
             f"{A_bat:.2f} * SNR^-{k_bat:.2f}; at SNR 7 / 30: fit "
             f"{A_fit * 7 ** -k_fit:.3f} / {A_fit * 30 ** -k_fit:.3f}, BAT 0.16 / 0.06)")

    L.append("")
    pair = [r for r in ok if "nolc" in r and "error" not in r["nolc"]]
    nerr = [r for r in ok if "nolc" in r and "error" in r["nolc"]]
    L.append(f"Light curve in the model vs constant (the same {len(pair)} bursts)"
             if pair or nerr else "Light curve in the model vs constant: not run here "
             "(--no-lc-subset 0); benchmarks/bursts_lightcurve_bias.py measures it")
    for r in nerr:
        L.append(f"  no-L(t) ERROR #{r['index']}: {r['nolc']['error']}")
    if pair:
        L.append(f"  {'':<22s} {'med sep':>8s} {'med r90':>8s} {'med sep/r90':>11s} "
                 f"{'cov90':>9s} {'cov68':>9s} {'mirror':>7s} {'med sqrtTS':>10s}")
        for lab, get in (("with L(t)", lambda r: r), ("constant", lambda r: r["nolc"])):
            g = [get(r) for r in pair]
            L.append(f"  {lab:<22s} {np.median([q['separation'] for q in g]):8.3f} "
                     f"{np.median([q['r90'] for q in g]):8.3f} "
                     f"{np.median([q['separation'] / q['r90'] for q in g]):11.3f} "
                     f"{sum(q['contains90'] for q in g):4d}/{len(g):<4d} "
                     f"{sum(q['contains68'] for q in g):4d}/{len(g):<4d} "
                     f"{sum(q['mirror_won'] for q in g):7d} "
                     f"{np.median([q['sqrt_ts'] for q in g]):10.1f}")
        # Bias: the mean offset of the fits from the truth in the instrument frame (radial
        # = theta, azimuthal = sin(theta) dphi), in units of each burst's r90, with its
        # standard error; bursts whose best position is another mode (> 3 r90 away) are
        # outliers, not bias, and are counted apart.
        def offsets(q, t):
            th, dphi = q["fit_theta"], (q["fit_phi"] - t["phi"] + 180.0) % 360.0 - 180.0
            return np.array([th - t["theta"],
                             math.sin(math.radians(t["theta"])) * dphi]) / q["r90"]
        for lab, get in (("with L(t)", lambda r: r), ("constant", lambda r: r["nolc"])):
            g = [(get(r), r["truth"]) for r in pair if "fit_theta" in get(r)]
            core = [offsets(q, t) for q, t in g if q["separation"] <= 3.0 * q["r90"]]
            if len(core) >= 2:
                o = np.array(core)
                m, e = o.mean(axis=0), o.std(axis=0, ddof=1) / math.sqrt(len(o))
                L.append(f"  bias {lab:<10s}: radial {m[0]:+.3f} +- {e[0]:.3f} r90, "
                         f"azimuthal {m[1]:+.3f} +- {e[1]:.3f} r90, |bias| "
                         f"{math.hypot(*m):.3f} r90 over {len(o)} bursts within 3 r90 "
                         f"({len(g) - len(o)} further: another mode)")
        rr = np.array([r["r90"] / r["nolc"]["r90"] for r in pair])
        ss = np.array([r["separation"] / r["nolc"]["separation"] for r in pair])
        L.append(f"  median r90(L)/r90(const) {np.median(rr):.3f}; median sep(L)/sep(const) "
                 f"{np.median(ss):.3f}; L(t) nearer the truth in "
                 f"{int(np.sum(ss < 1))}/{len(pair)}")

    L.append("")
    tt = [r for r in ok if np.isfinite(r["t90"]) and np.isfinite(r["t90_err"])]
    L.append(f"T90 against the truth (true_durations over {TRUTH_WINDOW[0]:g}-"
             f"{TRUTH_WINDOW[1]:g} s), {len(tt)} bursts with a finite T90")
    if tt:
        z = np.array([(r["t90"] - r["true_t90"]) / r["t90_err"] if r["t90_err"] > 0
                      else np.inf for r in tt])
        L.append(frac_line("|T90 - true| < 1 sigma", int(np.sum(np.abs(z) < 1)), len(tt))
                 + "   (Gaussian 0.683)")
        L.append(frac_line("|T90 - true| < 2 sigma", int(np.sum(np.abs(z) < 2)), len(tt))
                 + "   (Gaussian 0.954)")
        rel = np.array([r["t90"] / r["true_t90"] for r in tt])
        L.append(f"  median T90/true {np.median(rel):.3f}; median (T90-true)/sigma "
                 f"{np.median(z[np.isfinite(z)]):+.2f}; median sigma/T90 "
                 f"{np.median([r['t90_err'] / r['t90'] for r in tt]):.3f}")
        bad = [(r, zz) for r, zz in zip(tt, z, strict=False) if abs(zz) >= 3]
        for r, zz in bad[:10]:
            L.append(f"    |z|>=3: #{r['index']} T90 {r['t90']:.2f}+-{r['t90_err']:.2f} true "
                     f"{r['true_t90']:.2f} (z {zz:+.1f}) sqrtTS {r['sqrt_ts']:.1f} "
                     f"pulses {len(r['truth']['pulses'])}")
    L.append("")
    times = [(r["index"], r["analyse_time"], r.get("loadavg")) for r in ok]
    first = data.get("cold_index")
    cold = [t for t in times if t[0] == first]
    warm = [t[1] for t in times if t[0] != first]
    L.append("Latency of analyse_burst (light curve on)")
    if cold:
        L.append(f"  first (cold cache) #{cold[0][0]}: {cold[0][1]:.1f} s (load avg "
                 f"{cold[0][2]})")
    if warm:
        L.append(f"  warm cache: median {np.median(warm):.1f} s, max {np.max(warm):.1f} s, "
                 f"N {len(warm)}")
    loads = [t[2][0] for t in times if t[2]]
    if loads:
        L.append(f"  load average (1 min) at the calls: median {np.median(loads):.2f}, max "
                 f"{np.max(loads):.2f} on {os.cpu_count()} cores; NUMBA_NUM_THREADS="
                 f"{cfg.get('numba_threads')}")
    return "\n".join(L)


def _pipeline_md5() -> dict[str, str]:
    """Short hashes of the burst pipeline's source files (which code a record ran on)."""
    import hashlib

    import rotmod.bursts.analysis
    import rotmod.bursts.localisation
    import rotmod.bursts.posterior
    import rotmod.bursts.pulses
    return {m.__name__: hashlib.md5(Path(m.__file__).read_bytes()).hexdigest()[:12]
            for m in (rotmod.bursts.analysis, rotmod.bursts.localisation,
                      rotmod.bursts.posterior, rotmod.bursts.pulses)}


#: The configuration that makes files shards of one run (--report merges only those).
SAME_RUN = ("n", "seed", "shape", "src_md5", "no_lc_subset", "radius", "energy", "background",
            "amplitude")


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=100, help="bursts (default 100)")
    p.add_argument("--seed", type=int, default=SEED)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    p.add_argument("--no-lc-subset", type=int, default=30,
                   help="detected bursts also analysed with light_curve=False (default 30)")
    p.add_argument("--shape", choices=("norris", "gauss-exp"), default="norris",
                   help="the injected pulses' shape (default norris, the model's family)")
    p.add_argument("--resume", action="store_true", help="skip the bursts in --out")
    p.add_argument("--only", default=None,
                   help="comma-separated draw indices (< --n): run only these (e.g. the "
                        "misses of an earlier run; not a coverage sample)")
    p.add_argument("--shard", default="0/1",
                   help="K/N: only the bursts i with i %% N == K (run N processes, one core "
                        "each, into separate --out files; --report merges them)")
    p.add_argument("--reverse", action="store_true",
                   help="take the shard's bursts from the last (a second process on a shard "
                        "another one runs forward; --report keeps one record per burst)")
    p.add_argument("--report", nargs="*", type=Path, default=None,
                   help="only print the report of --out and of these other JSON files")
    p.add_argument("--compare", nargs="*", type=Path, default=None,
                   help="with --report: JSON files of an earlier run of the same draws, "
                        "compared burst by burst")
    args = p.parse_args(argv)
    global SHAPE
    SHAPE = args.shape
    out = args.out
    txt = out.with_suffix(".txt")
    if args.report is not None:
        data = json.loads(out.read_text())
        for extra in args.report:
            other = json.loads(extra.read_text())
            # Shards of one run only: a file of another run (another pipeline or draws)
            # would replace bursts of the same index and mix two calibrations.
            for key in SAME_RUN:
                if other["config"].get(key) != data["config"].get(key):
                    raise SystemExit(
                        f"--report: {extra} is not a shard of the run in --out {out} (its "
                        f"config {key!r} differs: {other['config'].get(key)!r} against "
                        f"{data['config'].get(key)!r})")
            data["bursts"] += other["bursts"]
        data["bursts"] = sorted({r["index"]: r for r in data["bursts"]}.values(),
                                key=lambda r: r["index"])
        if args.compare:
            data["compare"] = {str(r["index"]): r for f in args.compare
                               for r in json.loads(f.read_text())["bursts"]
                               if r.get("detected") and "error" not in r}
        text = report(data)
        print(text)
        txt.write_text(text + "\n")
        return
    try:
        shard, n_shards = (int(v) for v in args.shard.split("/"))
        assert 0 <= shard < n_shards
    except (ValueError, AssertionError):
        sys.exit(f"--shard: must be K/N with 0 <= K < N, got {args.shard!r}")
    inst, att = setup()
    src = _pipeline_md5()
    if args.resume and out.exists():
        data = json.loads(out.read_text())
        if data["config"]["seed"] != args.seed:
            sys.exit(f"--resume: {out} has seed {data['config']['seed']}, not {args.seed}")
        if data["config"].get("shape", "norris") != args.shape:
            sys.exit(f"--resume: {out} has pulses of shape {data['config'].get('shape')}, "
                     f"not {args.shape}")
        data["config"]["n"] = args.n
        last = (data["config"].get("resumed") or [data["config"]])[-1].get("src_md5")
        if src != last:
            # the pipeline's source changed since the run started: say so in the file, so
            # that a reader can tell which bursts ran on which code
            data["config"].setdefault("resumed", []).append({
                "at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "after_bursts": len(data["bursts"]), "src_md5": src})
    else:
        try:
            import numba
            threads = numba.config.NUMBA_NUM_THREADS
        except Exception:
            threads = None
        data = {"config": {"n": args.n, "src_md5": src, "started": time.strftime(
                               "%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "seed": args.seed,
                           "no_lc_subset": args.no_lc_subset, "shape": args.shape,
                           "radius": RADIUS, "energy": ENERGY, "background": BACKGROUND,
                           "theta": f"uniform in cos, 0-{THETA_MAX:g} deg",
                           "amplitude": list(AMP_RANGE), "numba_threads": threads,
                           "python": platform.python_version(), "host_cores": os.cpu_count()},
                "bursts": [], "cold_index": None}
    out.parent.mkdir(parents=True, exist_ok=True)
    done = {r["index"] for r in data["bursts"]}
    n_nolc = sum(1 for r in data["bursts"] if "nolc" in r)
    cache: dict = {}
    only = None if args.only is None else {int(v) for v in args.only.split(",")}
    for i in (range(args.n - 1, -1, -1) if args.reverse else range(args.n)):
        if i in done or i % n_shards != shard or (only is not None and i not in only):
            continue
        t0 = time.perf_counter()
        cold = not cache
        rec = run_one(i, args.seed, inst, att, cache,
                      do_nolc=n_nolc < args.no_lc_subset / n_shards)
        if "nolc" in rec:
            n_nolc += 1
        if cold and "analyse_time" in rec:
            data["cold_index"] = i
        rec["wall"] = time.perf_counter() - t0
        data["bursts"].append(rec)
        save(out, data)
        tr = rec["truth"]
        msg = (f"#{i:3d} th {tr['theta']:5.1f} amp {tr['amplitude']:6.1f} np "
               f"{len(tr['pulses'])} T90true {rec['true_t90']:6.2f} ")
        if not rec.get("detected"):
            msg += "MISSED"
        elif "error" in rec:
            msg += "ERROR " + rec["error"]
        else:
            msg += (f"sqrtTS {rec['sqrt_ts']:5.1f} sep {rec['separation']:.2f} r90 "
                    f"{rec['r90']:.2f} in90 {rec['contains90']:d} mirror {rec['mirror_won']:d} "
                    f"T90 {rec['t90']:.2f}+-{rec['t90_err']:.2f} t {rec['analyse_time']:.1f}s")
            if "nolc" in rec and "error" not in rec["nolc"]:
                msg += (f" | const sep {rec['nolc']['separation']:.2f} r90 "
                        f"{rec['nolc']['r90']:.2f}")
        print(msg, f"wall {rec['wall']:.1f}s load {os.getloadavg()[0]:.2f}", flush=True)
    text = report(data)
    print(text)
    txt.write_text(text + "\n")


if __name__ == "__main__":
    main()
