"""Fit rotmod's OGIP files with threeML or sherpa, as their users would, and print the result.

Run by tests/io/test_ogip.py in a process of its own: importing threeML restyles matplotlib
and changes warning filters for the whole interpreter, and neither client's state may leak
into other tests.

Usage: ``python ogip_clients.py {threeml,sherpa} SPECTRUM.pha [SPECTRUM.pha ...]``.  Each
spectrum is fitted with a power law started at ``K = 2e-4`` (at 100 keV), index -1.5: with
the Poisson background it names (BACKFILE) by the profile likelihood of both (threeML's
``poisson``/``poisson``, sherpa's ``wstat``), without one by chi-square on its errors.
Prints one JSON object per spectrum: the client's statistic names, its folded counts of
the start model, the fitted ``K`` and ``index`` (astromodels' sign: -2 is ``E^-2``), their
errors from the fit's covariance, and the statistic at the fit (``-2 ln L`` for threeML).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from astropy.io import fits

START_K, START_INDEX, PIVOT = 2e-4, -1.5, 100.0


def _files(path: Path) -> dict[str, str]:
    """The response, ancillary response and background files the PHA names."""
    with fits.open(path) as h:
        cards = h["SPECTRUM"].header
        return {key: str(path.parent / cards[card])
                for key, card in [("response", "RESPFILE"), ("arf_file", "ANCRFILE"),
                                  ("background", "BACKFILE")]
                if cards.get(card, "none").lower() != "none"}


def threeml(path: Path) -> dict[str, Any]:
    from astromodels import Model, PointSource, Powerlaw
    from threeML import DataList, JointLikelihood, LocalMinimization, OGIPLike

    # threeML resolves the PHA's cards against the working directory: pass them.
    plugin = OGIPLike("rotmod", observation=str(path), **_files(path))
    shape = Powerlaw(K=START_K, index=START_INDEX, piv=PIVOT)
    model = Model(PointSource("source", 0.0, 0.0, spectral_shape=shape))
    plugin.set_model(model)
    folded = np.asarray(plugin.get_model(), dtype=float)
    fitter = JointLikelihood(model, DataList(plugin), verbose=False)
    # Minuit's default tolerance stops ~1 % of an error short of the maximum; 1e-6 reaches it.
    minimizer = LocalMinimization("minuit")
    minimizer.setup(ftol=1e-6)
    fitter.set_minimizer(minimizer)
    fitter.fit(quiet=True)
    k, index = float(shape.K.value), float(shape.index.value)
    # The covariance is in threeML's internal parameters: K is fitted as log10(K).
    sigma = np.sqrt(np.diag(fitter.results.covariance_matrix))
    return {"statistic": [plugin.observation_noise_model, plugin.background_noise_model],
            "folded": folded.tolist(), "K": k, "index": index,
            "K_error": float(sigma[0] * k * np.log(10.0)), "index_error": float(sigma[1]),
            "value": float(-2.0 * plugin.get_log_like())}


def sherpa(path: Path) -> dict[str, Any]:
    from sherpa.astro import ui

    poisson = "background" in _files(path)
    ui.clean()
    # sherpa reads the cards relative to the PHA; a RATE file's STAT_ERR only if asked.
    ui.load_pha(str(path), use_errors=not poisson)
    ui.set_stat("wstat" if poisson else "chi2")
    ui.set_analysis("energy")
    p = ui.create_model_component("powlaw1d", "p")
    p.ref, p.ampl, p.gamma = PIVOT, START_K, -START_INDEX
    ui.set_source(p)
    folded = np.asarray(ui.get_data().eval_model(ui.get_model()), dtype=float)
    ui.set_method("levmar")
    ui.fit()
    ui.covar()
    err = ui.get_covar_results()
    errors = dict(zip(err.parnames, err.parmaxes, strict=True))
    return {"statistic": [ui.get_stat_name(), None], "folded": folded.tolist(),
            "K": float(p.ampl.val), "index": -float(p.gamma.val),
            "K_error": float(errors["p.ampl"]), "index_error": float(errors["p.gamma"]),
            "value": float(ui.get_fit_results().statval)}


if __name__ == "__main__":
    client = {"threeml": threeml, "sherpa": sherpa}[sys.argv[1]]
    for arg in sys.argv[2:]:
        print(json.dumps(client(Path(arg))))
