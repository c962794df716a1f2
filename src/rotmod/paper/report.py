"""``rotmod reproduce``: regenerate the seed paper's results into a folder with an HTML report.

Steps (each writes into ``<out>/<step>/`` through a temporary folder renamed at the end, so
an interrupted step leaves nothing that looks finished; a rerun skips steps whose
``result.json`` exists unless ``force``):

``profiles``
    Every validation scenario of :mod:`rotmod.paper.validation` (the paper's Figs. 4-8 set-ups,
    the two imaging set-ups and four geometries outside the advanced model's validity):
    Monte Carlo vs standard vs advanced vs exact, figures and chi-square per model.
``speed``
    Time to compute one detector's response for 4900 sky bins x 560 time bins with the
    standard, advanced G0, advanced G1~ and exact models (median of several runs) and the
    Monte Carlo time to reach SNR 10 per time bin (from its measured photon rate), beside
    the paper's IDL figures.
``images``
    The paper's three image figures (122 keV, 2 cm; 662 keV, 5 mm; 662 keV at 48 deg, 2 cm):
    Monte Carlo observations reconstructed with the standard, advanced and exact responses.
``prototype``
    The lab prototype's two sources 35' apart on a background as strong as both.
``summary``
    ``summary.png``: a profile comparison and a standard-vs-exact image comparison.

The report ``index.html`` is rewritten at the end of every run from the steps' results.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import astropy.units as u
import numba
import numpy as np

from rotmod.compilation import MC_OBSERVATION, compile_in_background
from rotmod.errors import ModelValidityError, ParameterError
from rotmod.geometry import Instrument
from rotmod.io.atomic import atomic_dir, atomic_path, remove_stale_dirs, write_text
from rotmod.io.figures import save_figure
from rotmod.io.images import write_image
from rotmod.materials import PAPER_SIGMA_662
from rotmod.montecarlo import simulate_profiles
from rotmod.paper import scenarios, validation
from rotmod.paper.claims import (
    IMAGE_CLAIMS,
    MONTE_CARLO,
    OUTSIDE,
    PAPER_SPEED_S,
    PROFILE_CLAIMS,
    PROTO_CLAIM,
    SPEED_LABEL,
)
from rotmod.paper.page import write_report
from rotmod.paper.provenance import provenance
from rotmod.paper.selection import (
    IMAGE_PAIR,
    REFERENCE_MODEL,
    SPEED_MODELS,
    VALIDATION_MODELS,
    check_registered,
)
from rotmod.plotting.images import plot_comparison, plot_image
from rotmod.plotting.profiles import plot_profiles
from rotmod.profiles import DEFAULT_COMPARISON, MODELS, get_model
from rotmod.reconstruction import ALGORITHMS, get_algorithm, reconstruct
from rotmod.reconstruction.metrics import evaluate
from rotmod.registry import Registry
from rotmod.response import TimeBinning, build_response
from rotmod.sky import SkyGrid

__all__ = ["SIZES", "STEPS", "ReproduceResult", "reproduce"]

STEPS = ("profiles", "speed", "images", "prototype", "summary")

#: The imaging scenarios of the paper's image figures (the prototype is its own step).
_IMAGE_SCENARIOS = tuple(IMAGE_CLAIMS)
#: The imaging scenario of the lab prototype.
_PROTOTYPE = "d"

#: Run sizes by name.  ``tiny`` is for the test suite (seconds; results not meaningful).
#: The scenarios, models and methods they name are registry names, checked when this module
#: is imported.
SIZES: Registry[dict[str, Any]] = Registry("size")
for _size, _cfg in {
    "tiny": {
        "scenarios": ("thick20", "wide50"), "n_photons": 1500, "n_angles": 72,
        "speed_grid": (20, 20), "speed_bins": 56, "speed_repeats": 1, "mc_photons": 2e5,
        "image_scenarios": _IMAGE_SCENARIOS[:1], "image_size": "small",
        "image_models": IMAGE_PAIR, "methods": ("mlem",), "max_iter": 60, "prototype": False,
        "bin_mode": "center", "proto_models": (), "proto_methods": (),
    },
    "quick": {
        "scenarios": None, "n_photons": 20000, "n_angles": 180,
        "speed_grid": (70, 70), "speed_bins": 560, "speed_repeats": 3, "mc_photons": 2e7,
        "image_scenarios": _IMAGE_SCENARIOS, "image_size": "small",
        "image_models": DEFAULT_COMPARISON, "methods": ("mlem",),
        "max_iter": None, "prototype": True, "bin_mode": "center",
        "proto_models": (REFERENCE_MODEL,), "proto_methods": ("mlem", "ncar"),
    },
    "full": {
        "scenarios": None, "n_photons": 200000, "n_angles": 360,
        "speed_grid": (70, 70), "speed_bins": 560, "speed_repeats": 7, "mc_photons": 2e8,
        "image_scenarios": _IMAGE_SCENARIOS, "image_size": "full",
        "image_models": DEFAULT_COMPARISON, "methods": ("mlem", "ncar"),
        "max_iter": None, "prototype": True, "bin_mode": "average",
        "proto_models": DEFAULT_COMPARISON, "proto_methods": ("mlem", "ncar"),
    },
}.items():
    SIZES.register(_size, _cfg)
    check_registered(validation.SCENARIOS, _cfg["scenarios"] or (), f"SIZES[{_size!r}]")
    check_registered(MODELS, (*_cfg["image_models"], *_cfg["proto_models"]),
                     f"SIZES[{_size!r}]")
    check_registered(ALGORITHMS, (*_cfg["methods"], *_cfg["proto_methods"]),
                     f"SIZES[{_size!r}]")
check_registered(scenarios.SCENARIOS, (*_IMAGE_SCENARIOS, _PROTOTYPE), "report scenarios")


@dataclass
class ReproduceResult:
    """What :func:`reproduce` wrote.

    Attributes
    ----------
    output : Path
    index : Path
        The HTML report.
    summary : Path or None
        The summary figure (None when the summary step could not run).
    run_time : float
        Wall time of this run (s).
    steps : dict
        Each step's result (as in its ``result.json``).
    """

    output: Path
    index: Path
    summary: Path | None
    run_time: float
    steps: dict[str, dict[str, Any]] = field(default_factory=dict)


# --------------------------------------------------------------------------- plumbing


def _json_default(o: Any) -> Any:
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    return str(o)


def _clean(o: Any) -> Any:
    """Replace non-finite floats by None so the JSON is strict."""
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, list | tuple):
        return [_clean(v) for v in o]
    if isinstance(o, float | np.floating) and not np.isfinite(o):
        return None
    return o


def _write_json(path: Path, obj: Any) -> None:
    text = json.dumps(_clean(json.loads(json.dumps(obj, default=_json_default))), indent=1)
    write_text(path, text)


def _savefig(fig: Any, path: Path, dpi: int = 110) -> str:
    """Save ``fig`` (:func:`rotmod.io.figures.save_figure`) and close it; the file's name."""
    import matplotlib.pyplot as plt

    try:
        save_figure(fig, path, dpi=dpi)
    finally:
        plt.close(fig)
    return path.name


def _run_step(
    name: str, out: Path, fn: Callable[[Path], dict[str, Any]], *, force: bool,
    log: Callable[[str], None],
) -> dict[str, Any]:
    final = out / name
    done = final / "result.json"
    if done.exists() and not force:
        log(f"[{name}] done already ({final}); skipped (use --force to redo)")
        return json.loads(done.read_text())
    t0 = time.perf_counter()
    log(f"[{name}] running...")
    with atomic_dir(final) as tmp:
        res = fn(tmp)
        res["step_time_s"] = time.perf_counter() - t0
        _write_json(tmp / "result.json", res)
    log(f"[{name}] finished in {res['step_time_s']:.1f} s")
    return json.loads(done.read_text())


def _progress(total: int, enabled: bool) -> Any:
    if not enabled:
        return contextlib.nullcontext(None)
    from tqdm.auto import tqdm  # only with a progress bar (~20 ms)

    return tqdm(total=total, desc="reproduce", unit="step")


# --------------------------------------------------------------------------- steps


def _step_profiles(tmp: Path, cfg: dict[str, Any], seed: int, log: Callable) -> dict[str, Any]:
    import matplotlib.pyplot as plt

    names = cfg["scenarios"] or validation.SCENARIOS.names()
    rows = []
    for k, name in enumerate(names):
        log(f"[profiles] scenario {name} ({k + 1}/{len(names)})")
        r = validation.run_scenario(name, n_photons=cfg["n_photons"], n_angles=cfg["n_angles"],
                                    seed=seed + k)
        sc = r.scenario
        fig, axes = plt.subplots(2, 1, figsize=(7.5, 5.2))
        validation.plot_scenario(r, detector=0, source=0, ax=axes[0])
        validation.plot_scenario(r, detector=len(sc.detectors) - 1,
                                 source=len(sc.phi_deg) - 1, ax=axes[1])
        fig.tight_layout()
        fig_name = _savefig(fig, tmp / f"profile_{name}.png")
        np.savez_compressed(
            tmp / f"profile_{name}.npz", xi=r.xi, mc=r.mc.fraction[0, :, 0],
            mc_err=r.mc.error[0, :, 0],
            **{f"model_{m}": p[0, :, 0] for m, p in r.profiles.items()},
        )
        rows.append({
            "name": name, "title": sc.title, "paper": sc.paper,
            "advanced_valid": sc.advanced_valid,
            "claim": PROFILE_CLAIMS.get(name, OUTSIDE),
            "chi2_dof": r.chi2_dof, "max_dev": r.max_dev,
            "skipped": {m: s.split(";")[0][:160] for m, s in r.skipped.items()},
            "n_photons": int(cfg["n_photons"]), "n_angles": int(cfg["n_angles"]),
            "figure": fig_name,
        })
    return {"scenarios": rows}


def _median_time(fn: Callable[[], Any], repeats: int) -> float:
    fn()  # warm-up (JIT, caches)
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _step_speed(tmp: Path, cfg: dict[str, Any], seed: int, log: Callable) -> dict[str, Any]:
    inst = Instrument.paper(sigma=PAPER_SIGMA_662)  # the paper's timing set-up (its sigma)
    grid = SkyGrid(cfg["speed_grid"], 14.0 / cfg["speed_grid"][0])
    theta, phi = grid.directions()
    n_bins = cfg["speed_bins"]
    xi = (np.arange(n_bins) + 0.5) * (360.0 / n_bins)  # deg
    rows = []
    for name in SPEED_MODELS:
        log(f"[speed] {name}")
        model = get_model(name)
        t = _median_time(
            lambda model=model: model.profile(inst, theta, phi, xi, dtype=np.float32),
            cfg["speed_repeats"],
        )
        rows.append({"model": name, "label": SPEED_LABEL[name], "time_s": t,
                     "paper_s": PAPER_SPEED_S[name]})
    # Monte Carlo: measured photon rate, extrapolated to SNR 10 per time bin.
    log("[speed] Monte Carlo photon rate")
    rng = np.random.default_rng(seed)
    pick = rng.choice(theta.size, size=min(64, theta.size), replace=False)
    n_ang = 56
    xi_mc = (np.arange(n_ang) + 0.5) * (360.0 / n_ang)  # deg
    per_cell = max(1, int(cfg["mc_photons"] // (pick.size * n_ang)))
    simulate_profiles(inst, theta[pick[:2]], phi[pick[:2]], xi_mc[:2], n_photons=1000, seed=0)
    t0 = time.perf_counter()
    mc = simulate_profiles(inst, theta[pick], phi[pick], xi_mc, n_photons=per_cell, seed=seed)
    dt = time.perf_counter() - t0
    n_total = per_cell * pick.size * n_ang
    rate = n_total / dt
    mean_p = float(mc.fraction.mean())
    # SNR 10 per time bin: 100 transmitted photons per (time bin, sky bin) at the mean
    # transmission, i.e. 100 / mean_p incident photons per cell.
    need = 4900 * 560 * 100.0 / max(mean_p, 1e-9)
    rows.append({"model": MONTE_CARLO, "label": SPEED_LABEL[MONTE_CARLO],
                 "time_s": need / rate, "paper_s": PAPER_SPEED_S[MONTE_CARLO],
                 "note": f"estimated: {need:.3g} photons at the measured "
                         f"{rate:.3g} photons/s ({n_total:.3g} photons in {dt:.2f} s; "
                         f"mean transmission {mean_p:.3f})"})
    return {
        "rows": rows, "grid": list(grid.shape), "n_bins": n_bins,
        "n_sky": int(grid.size), "repeats": int(cfg["speed_repeats"]),
        "threads": int(numba.get_num_threads()), "cpus": os.cpu_count(),
        "paper_size": grid.size == 4900 and n_bins == 560,
    }


def _image_case(
    tmp: Path, name: str, cfg: dict[str, Any], seed: int, log: Callable, *, prefix: str,
) -> dict[str, Any]:
    import matplotlib.pyplot as plt

    log(f"[{prefix}] scenario {name}: Monte Carlo observation")
    sc = scenarios.make_scenario(name, cfg["image_size"], seed=seed)
    tb = sc.time_bins
    if cfg["bin_mode"] == "center":
        tb = TimeBinning(sc.time_bins.n_bins, "center")
    out: dict[str, Any] = {
        "name": name, "description": sc.description, "energy_keV": sc.energy,
        "counts": sc.counts, "exposure_s": sc.duration,
        "background_per_det": sc.background_rate, "n_det": len(sc.instrument.detectors),
        "grid": sc.grid.to_dict(), "n_bins": tb.n_bins, "bin_mode": tb.mode,
        "resolution_deg": sc.resolution,
        "sources_deg": np.column_stack([v.to_value("deg") for v in sc.sources]).tolist(),
        "results": [],
    }
    images: dict[str, np.ndarray] = {}
    for model in cfg["image_models"]:
        log(f"[{prefix}] scenario {name}: {model} response")
        try:
            resp = build_response(sc.instrument, sc.grid, tb, model=model, energy=sc.energy,
                                  dtype=np.float64)
        except ModelValidityError as exc:
            out["results"].append({"model": model, "skipped": str(exc).split(";")[0]})
            continue
        for method in cfg["methods"]:
            kw = dict(sc.reconstruct_kwargs)
            if sc.stopping is not None and get_algorithm(method).iterative:
                kw["stopping"] = sc.stopping
            if cfg["max_iter"]:
                kw["max_iter"] = cfg["max_iter"]
            log(f"[{prefix}] scenario {name}: {model} + {method}")
            res = reconstruct(resp, sc.folded, method, seed=seed, **kw)
            m = evaluate(res, sc.grid, sc.sources, true_flux=sc.flux, radius=sc.radius,
                         resolution=sc.resolution)
            out["results"].append({"model": model, "method": method, **m})
            images[f"{model}|{method}"] = res.image
            fits_name = f"{prefix}_{name}_{model}_{method}.fits"
            write_image(tmp / fits_name, res, meta={"scenario": name, "response": model})
            out.setdefault("fits", []).append(fits_name)
    np.savez_compressed(tmp / f"{prefix}_{name}.npz",
                        theta_deg=sc.theta.to_value("deg"), phi_deg=sc.phi.to_value("deg"),
                        **images)
    if images:
        keys = list(images)
        fig, axes = plt.subplots(1, len(keys), figsize=(3.3 * len(keys), 3.2), squeeze=False)
        plot_comparison([images[k] for k in keys], sc.grid,
                        titles=[k.replace("|", " + ") for k in keys], sources=sc.sources,
                        axes=axes[0])
        fig.suptitle(sc.description, fontsize=9)
        fig.tight_layout()
        out["figure"] = _savefig(fig, tmp / f"{prefix}_{name}.png")
    return out


def _step_images(tmp: Path, cfg: dict[str, Any], seed: int, log: Callable) -> dict[str, Any]:
    cases = []
    for k, name in enumerate(cfg["image_scenarios"]):
        case = _image_case(tmp, name, cfg, seed + k, log, prefix="image")
        case["claim"] = IMAGE_CLAIMS[name]
        cases.append(case)
    skipped = [n for n in _IMAGE_SCENARIOS if n not in cfg["image_scenarios"]]
    return {"cases": cases, "not_run": skipped}


def _step_prototype(tmp: Path, cfg: dict[str, Any], seed: int, log: Callable) -> dict[str, Any]:
    if not cfg["prototype"]:
        return {"not_run": "the tiny run skips the prototype case"}
    pcfg = {**cfg, "image_models": cfg["proto_models"], "methods": cfg["proto_methods"]}
    case = _image_case(tmp, _PROTOTYPE, pcfg, seed, log, prefix="prototype")
    case["claim"] = PROTO_CLAIM
    return {"case": case}


def _step_summary(out: Path, tmp: Path, log: Callable) -> dict[str, Any]:
    import matplotlib.pyplot as plt

    prof = None
    for name in ("thick20", "wide50", "zen48"):
        p = out / "profiles" / f"profile_{name}.npz"
        if p.exists():
            prof = (name, np.load(p))
            break
    imgs = None
    res_path = out / "images" / "result.json"
    if res_path.exists():
        cases = json.loads(res_path.read_text()).get("cases", [])
        order = {"c": 0, "b": 1, "a": 2}
        for case in sorted(cases, key=lambda c: order.get(c["name"], 9)):
            f = out / "images" / f"image_{case['name']}.npz"
            if f.exists():
                d = np.load(f)
                keys = [k for k in d.files if "|" in k]
                std = [k for k in keys if k.startswith(f"{IMAGE_PAIR[0]}|")]
                exa = [k for k in keys if k.startswith(f"{IMAGE_PAIR[1]}|")]
                if std and exa:
                    imgs = (case, d, std[0], exa[0])
                    break
    fig = plt.figure(figsize=(10, 7.2))
    gs = fig.add_gridspec(2, 2, height_ratios=[1.0, 1.25])
    ax0 = fig.add_subplot(gs[0, :])
    if prof is not None:
        name, d = prof
        models = {m[6:]: d[m] for m in d.files if m.startswith("model_")
                  and m[6:] in DEFAULT_COMPARISON}
        plot_profiles(d["xi"] * u.rad, models, mc=d["mc"], mc_error=d["mc_err"], ax=ax0,
                      title=f"profile: Monte Carlo vs models, scenario {name}")
    else:
        ax0.text(0.5, 0.5, "profiles step not run", ha="center", transform=ax0.transAxes)
    if imgs is not None:
        case, d, ks, ke = imgs
        grid = SkyGrid.from_dict(case["grid"])
        for j, k in enumerate((ks, ke)):
            ax = fig.add_subplot(gs[1, j])
            plot_image(d[k], grid, sources=(d["theta_deg"], d["phi_deg"]), ax=ax,
                       title=f"{k.replace('|', ' response + ')} ({case['name']}: "
                             f"{case['energy_keV']:g} keV)")
    else:
        ax = fig.add_subplot(gs[1, :])
        ax.text(0.5, 0.5, "image step not run or reconstruction not available", ha="center",
                transform=ax.transAxes)
        ax.set_axis_off()
    fig.suptitle("rotmod reproduces Budden et al.: profiles (top) and standard vs exact "
                 "response images (bottom)", fontsize=10)
    fig.tight_layout()
    _savefig(fig, tmp / "summary.png", dpi=100)
    return {"figure": "summary.png", "profile_scenario": prof[0] if prof else None,
            "image_case": imgs[0]["name"] if imgs else None}


# --------------------------------------------------------------------------- entry point


def reproduce(
    output: str | os.PathLike,
    *,
    size: str = "quick",
    force: bool = False,
    steps: Sequence[str] | None = None,
    seed: int = 1,
    log: Callable[[str], None] | None = None,
    progress: bool = False,
) -> ReproduceResult:
    """Regenerate the seed paper's results into ``output`` (see the module notes).

    Parameters
    ----------
    output : path
        Output folder (created if needed).
    size : {"quick", "full", "tiny"}
        Run size (:data:`SIZES`); ``tiny`` is for tests.
    force : bool
        Redo steps whose outputs exist.
    steps : sequence of str, optional
        Subset of :data:`STEPS` to run (default all).
    seed : int
        Base seed of every Monte Carlo and randomised reconstruction.
    log : callable, optional
        Receives one progress line per step (the CLI prints them to stderr).
    progress : bool
        Show a progress bar over the steps (tqdm).

    Returns
    -------
    ReproduceResult
    """
    cfg = SIZES.get(size)
    chosen = list(STEPS) if steps is None else list(steps)
    bad = [s for s in chosen if s not in STEPS]
    if bad:
        raise ParameterError(f"steps must be among {list(STEPS)}, got {bad}")
    say = log or (lambda msg: None)
    import matplotlib

    matplotlib.use("Agg", force=True)
    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    marker = out / "reproduce.json"
    if marker.exists():
        prev = json.loads(marker.read_text()).get("size")
        if prev != size and not force:
            raise ParameterError(
                f"output {str(out)!r} holds a {prev!r} run; use another folder or --force to "
                f"redo it as {size!r}"
            )
    prov = provenance(seed)
    _write_json(marker, {"size": size, "seed": seed, "provenance": prov})
    remove_stale_dirs(out)
    t0 = time.perf_counter()
    results: dict[str, dict[str, Any]] = {}
    fns: dict[str, Callable[[Path], dict[str, Any]]] = {
        "profiles": lambda tmp: _step_profiles(tmp, cfg, seed, say),
        "speed": lambda tmp: _step_speed(tmp, cfg, seed, say),
        "images": lambda tmp: _step_images(tmp, cfg, seed, say),
        "prototype": lambda tmp: _step_prototype(tmp, cfg, seed, say),
        "summary": lambda tmp: _step_summary(out, tmp, say),
    }
    order = [s for s in STEPS if s in chosen]
    # On a machine's first run the first step compiles the Monte Carlo's profile kernel and
    # the exact model's (~8 s on 2 cores); meanwhile a second process compiles the other
    # models' and the event Monte Carlo's, in the order the steps reach them, and this one
    # finds them in the cache (benchmarks/bench_coldstart.py).
    later = [m for m in VALIDATION_MODELS if m != REFERENCE_MODEL] + [MC_OBSERVATION]
    with _progress(len(order), progress) as bar, compile_in_background(later) as bg:
        for i, name in enumerate(order):
            if name == "speed":
                bg.finish()  # the timings have the cores to themselves
            say(f"step {i + 1}/{len(chosen)}: {name}")
            results[name] = _run_step(name, out, fns[name], force=force or name == "summary",
                                      log=say)
            src = out / "summary" / "summary.png"
            if name == "summary" and src.exists():
                with atomic_path(out / "summary.png") as tmp:
                    shutil.copyfile(src, tmp)
            if bar is not None:
                bar.update(1)
    run_time = time.perf_counter() - t0
    total = 0.0
    for s in STEPS:
        p = out / s / "result.json"
        if p.exists():
            total += json.loads(p.read_text()).get("step_time_s", 0.0)
    index = write_report(out, steps=STEPS, size=size, run_time=run_time, total_time=total,
                         provenance=prov)
    summary = out / "summary.png"
    return ReproduceResult(out, index, summary if summary.exists() else None, run_time, results)
