"""The report page: the steps' ``result.json`` files rendered through a jinja2 template.

The page's layout lives in ``templates/index.html.j2`` (autoescaped); this module only turns
results into rows of text.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rotmod.io.atomic import write_text
from rotmod.paper.provenance import provenance as make_provenance
from rotmod.paper.selection import VALIDATION_MODELS

__all__ = ["fmt_time", "write_report"]


def _fmt(v: Any, spec: str = ".3g") -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int | float):
        return format(v, spec)
    return str(v)


def fmt_time(s: float | None) -> str:
    """A duration in the unit that reads best (ms, s, min, h, days)."""
    if s is None:
        return "–"
    for limit, div, unit, spec in ((86400, 86400, "days", ".2g"), (3600, 3600, "h", ".2g"),
                                   (60, 60, "min", ".2g"), (1, 1, "s", ".3g")):
        if s >= limit:
            return f"{s / div:{spec}} {unit}"
    return f"{s * 1e3:.3g} ms"


def _profiles(res: dict[str, Any] | None) -> dict[str, Any] | None:
    if not res:
        return None
    rows, blocks = [], []
    for s in res["scenarios"]:
        cells: list[Any] = [(s["name"], s["title"]), s["paper"]]
        for m in VALIDATION_MODELS:
            if m in s["chi2_dof"]:
                cells.append((_fmt(s["chi2_dof"][m]), f"max |Δ| {_fmt(s['max_dev'][m], '.3f')}"))
            else:
                cells.append(("", "n/a"))
        rows.append(cells)
        best = min(s["chi2_dof"], key=lambda m: s["chi2_dof"][m]) if s["chi2_dof"] else None
        obtained = "; ".join(f"{m}: χ²/dof {_fmt(v)}" for m, v in s["chi2_dof"].items())
        if s["skipped"]:
            obtained += "; refused: " + ", ".join(s["skipped"])
        blocks.append({**s, "obtained": obtained, "best": str(best)})
    first = res["scenarios"][0]
    return {"n_photons": first["n_photons"], "n_angles": first["n_angles"],
            "header": ["scenario", "paper", *VALIDATION_MODELS], "rows": rows,
            "scenarios": blocks}


def _speed(res: dict[str, Any] | None) -> dict[str, Any] | None:
    if not res:
        return None
    rows = []
    for r in res["rows"]:
        ratio = (f"{r['paper_s'] / r['time_s']:.3g}×" if r.get("time_s") and r.get("paper_s")
                 else "–")
        rows.append([r["label"], fmt_time(r.get("paper_s")), fmt_time(r.get("time_s")), ratio,
                     ("", r.get("note", ""))])
    return {
        **res, "rows": rows,
        "header": ["computation", "paper (IDL)", "rotmod", "speed-up", "note"],
        "size": f"{res['n_sky']} sky bins ({res['grid'][0]}×{res['grid'][1]}) × "
                f"{res['n_bins']} time bins",
    }


def _case(case: dict[str, Any], folder: str) -> dict[str, Any]:
    two = len(case["sources_deg"]) == 2
    rows = []
    for r in case["results"]:
        if "skipped" in r:
            rows.append([r["model"], "–", f"refused: {r['skipped']}", "", "", "", "", ""])
            continue
        extra = _fmt(r.get("dip"), ".3f") if two else _fmt(r.get("fwhm_over_bL"), ".2f")
        rows.append([
            r["model"], r["method"], _fmt(r["loc_err_max"], ".3f"), _fmt(r["spurious"], ".3f"),
            _fmt(r["flux_ratio"], ".3f"), extra, _fmt(r["chi2_dof"], ".3f"),
            f"{int(r['n_iter'])} / {_fmt(r['run_time'], '.2g')} s",
        ])
    src = "; ".join(f"θ = {t:.3g}°, φ = {p:.3g}°" for t, p in case["sources_deg"])
    g = case["grid"]
    setup = (
        f"Monte Carlo observation: {case['n_det']} detector(s), {case['energy_keV']:g} keV, "
        f"{case['exposure_s']:g} s, {case['counts']} counts, background "
        f"{case['background_per_det']:g} /s per detector; source(s) {src}; grid "
        f"{g['shape'][1]}×{g['shape'][0]} pixels of {g['pixel_size']:.3g}° of the tangent "
        f"plane centred at ({g['center'][0]:.3g}°, {g['center'][1]:.3g}°); {case['n_bins']} "
        f"time bins ({case['bin_mode']}); b/L = {case['resolution_deg']:.3g}°."
    )
    got = []
    for r in case["results"]:
        if "loc_err_max" not in r:
            continue
        s = (f"{r['model']} + {r['method']}: source found within "
             f"{_fmt(r['loc_err_max'], '.2f')}°, spurious/true {_fmt(r['spurious'], '.2f')}")
        if "dip" in r:
            s += f", dip {_fmt(r['dip'], '.2f')}"
        got.append(s)
    return {
        "description": case["description"], "claim": case["claim"], "setup": setup,
        "header": ["response", "method", "localisation error (deg)",
                   "strongest spurious peak / true peak", "recovered flux / true",
                   "dip between sources (<1: resolved)" if two else "FWHM / (b/L)",
                   "χ²/dof", "iterations / time"],
        "rows": rows, "got": "; ".join(got),
        "figure": f"{folder}/{case['figure']}" if case.get("figure") else None,
        "fits": [f"{folder}/{f}" for f in case.get("fits", [])],
    }


def _images(res: dict[str, Any] | None) -> dict[str, Any] | None:
    if not res:
        return res
    return {"cases": [_case(c, "images") for c in res["cases"]], "not_run": res.get("not_run")}


def _prototype(res: dict[str, Any] | None) -> dict[str, Any] | None:
    if not res or res.get("not_run"):
        return res
    return {"case": _case(res["case"], "prototype")}


def write_report(
    output: str | os.PathLike, *, steps: Sequence[str], size: str, run_time: float | None,
    total_time: float | None = None, provenance: dict[str, Any] | None = None,
) -> Path:
    """Render ``<output>/index.html`` from the steps' ``result.json`` files.

    Parameters
    ----------
    output : path
        The reproduce folder.
    steps : sequence of str
        The step names, in the report's order.
    size : str
        The run size shown in the report.
    run_time : float or None
        Wall time of the last run (s).
    total_time : float or None
        Sum of the steps' own times (s), including steps done in earlier runs.
    provenance : dict, optional
        :func:`rotmod.paper.provenance.provenance` of the run (default: made now).

    Returns
    -------
    Path
    """
    import jinja2  # only the report's page needs it

    out = Path(output)
    res: dict[str, Any] = {}
    for s in steps:
        p = out / s / "result.json"
        res[s] = json.loads(p.read_text()) if p.exists() else None
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("rotmod.paper", "templates"),
        autoescape=True, undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True,
    )
    steps_t = "; ".join(f"{s} {res[s]['step_time_s']:.1f} s" for s in steps
                        if res[s] and "step_time_s" in res[s])
    text = env.get_template("index.html.j2").render(
        prov=provenance or make_provenance(), size=size, when=time.strftime("%Y-%m-%d %H:%M:%S"),
        run_time=fmt_time(run_time), total_time=fmt_time(total_time) if total_time else None,
        steps_t=steps_t, summary=(out / "summary.png").exists(),
        profiles=_profiles(res.get("profiles")), speed=_speed(res.get("speed")),
        images=_images(res.get("images")), prototype=_prototype(res.get("prototype")),
    )
    return write_text(out / "index.html", text)
