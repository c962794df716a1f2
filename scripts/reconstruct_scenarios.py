"""Full-size reconstruction scenarios: Monte Carlo data, every algorithm, each response model.

Writes ``docs/figures/recon_metrics.md`` (metrics table) and ``docs/figures/recon_*.png``.
Run: ``python scripts/reconstruct_scenarios.py [--size small|full] [--out docs/figures]``.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from rotmod.io.atomic import write_text
from rotmod.paper.scenarios import SCENARIOS, make_scenario
from rotmod.reconstruction import get_algorithm, reconstruct
from rotmod.reconstruction.metrics import evaluate, measure

log = logging.getLogger("reconstruct_scenarios")

MODELS = {"a": ("standard", "advanced-approx"), "b": ("standard", "advanced-approx", "exact"),
          "c": ("standard", "advanced-approx", "exact"), "d": ("standard", "advanced-approx")}
# NCAR on its SIRT core: the recorded table predates issue 11's SGP core (the new solvers
# are compared in benchmarks/bench_reconstruction.py).
METHODS = (("backprojection", {}), ("mlem", {}), ("mart", {}),
           ("ncar", {"n_layers": 0, "core": "sirt"}), ("ncar", {"n_layers": 3, "core": "sirt"}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--size", default="full", choices=("small", "full"))
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument("--scenarios", default="".join(SCENARIOS))
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from rotmod.plotting import plot_comparison

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows, info = [], []
    for name in args.scenarios:
        sc = make_scenario(name, args.size, seed=1)
        info.append(
            f"- **({name})** {sc.description}: {sc.counts} counts in {sc.duration:.0f} s "
            f"({sc.folded.exposure[0]:.2f} s per bin x {sc.time_bins.n_bins} bins x "
            f"{len(sc.instrument.detectors)} detectors), source rate {sc.flux.tolist()} /s "
            f"per detector face, background {sc.background_rate:g} /s per detector; grid "
            f"{sc.grid.shape} x {sc.grid.pixel_size:.3f} deg centred at "
            f"({sc.grid.center[0]:.2f}, {sc.grid.center[1]:.2f}) deg."
        )
        log.info(info[-1])
        best: dict[str, np.ndarray] = {}
        for model in MODELS[name]:
            resp, t_resp, _ = measure(sc.response, model)
            for method, kw in METHODS:
                if sc.stopping is not None and get_algorithm(method).iterative:
                    kw = {**kw, "stopping": sc.stopping}
                res, dt, mem = measure(
                    reconstruct, resp, sc.folded, method, seed=3, **sc.reconstruct_kwargs, **kw
                )
                m = evaluate(res, sc.grid, sc.sources, true_flux=sc.flux, radius=sc.radius,
                             resolution=sc.resolution)
                label = method + (f"(K={kw['n_layers']})" if "n_layers" in kw else "")
                rows.append((name, model, label, m, dt, mem, t_resp))
                log.info("%s %s %s %s", name, model, label,
                         {k: round(v, 3) for k, v in m.items()})
                if method == "ncar" and kw["n_layers"] > 0:
                    best[model] = res.image
                if method == "ncar" and kw["n_layers"] == 0:
                    best[model + " K=0"] = res.image
        keys = [k for k in best if "K=0" not in k]
        axes = plot_comparison([best[k] for k in keys], sc.grid, sources=sc.sources,
                               titles=[f"({name}) {k}, NCAR" for k in keys], colorbar=False)
        axes[0].figure.savefig(out / f"recon_{name}.png", dpi=80)
        plt.close(axes[0].figure)
        good = keys[-1]
        axes = plot_comparison([best[good + " K=0"], best[good]], sc.grid, sources=sc.sources,
                               titles=[f"({name}) {good}: no layers", "K=3 noise layers"],
                               colorbar=False)
        axes[0].figure.savefig(out / f"recon_{name}_layers.png", dpi=80)
        plt.close(axes[0].figure)
    lines = ["| scen | response | method | loc err (deg) | spurious | FWHM/(b/L) | dip | "
             "flux | chi2/dof | iters | time (s) | peak mem (MB) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, model, label, m, dt, mem, _ in rows:
        lines.append(
            f"| {name} | {model} | {label} | {m['loc_err_max']:.3f} | {m['spurious']:.2f} | "
            f"{m.get('fwhm_over_bL', float('nan')):.2f} | {m.get('dip', float('nan')):.2f} | "
            f"{m['flux_ratio']:.2f} | {m['chi2_dof']:.3f} | {m['n_iter']:.0f} | {dt:.2f} | "
            f"{mem:.1f} |"
        )
    write_text(out / "recon_metrics.md", "\n".join(info) + "\n\n" + "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
