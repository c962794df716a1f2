"""Calibration of per-source spectra extracted from the modulator's counts (issue 23).

A field of two power-law sources on a background unknown to the fit (the survey instrument of
benchmarks/spectra_calibration.py: 37 detectors of 5 cm x 5 cm NaI(Tl) under 3/3/3 cm lead
slats 1 m up, 60 mask-angle bins, 64 true-energy nodes, 32 channels).  Each Poisson
realisation is analysed twice:

* extracted: :func:`rotmod.sources.spectra.extract_spectrum` (source 0, every source's pattern
  from the default E^-2 template), then a chi-square fit of the extracted rates through the
  response that comes with them (:func:`rotmod.spectral.fit_spectrum`) -- what XSPEC would do
  with the OGIP files;
* joint: :func:`rotmod.sources.spectra.fit_spectra`, the Poisson forward-folded fit of both
  sources' spectra on all the counts.

Reports per method the index's and K's coverage, mean pull and pull width, the chi-square of
the extracted fits, and the difference of the two methods in units of the joint fit's error.

    NUMBA_NUM_THREADS=1 python benchmarks/spectra_extraction.py --n 200 --out r.json
    NUMBA_NUM_THREADS=1 python benchmarks/spectra_extraction.py --n 100 --hours 0.5 0.05
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from spectra_calibration import save, survey, wilson

from rotmod.sources.spectra import expected_counts, extract_spectrum, fit_spectra
from rotmod.spectral import PowerLaw, fit_spectrum


def run_case(cols, bkg, truth, start, hours, n, rng, n_bins) -> dict:
    """``n`` realisations of an observation of ``hours``: pulls of both methods, their
    difference and the extracted fits' chi-square (printed and returned)."""
    expo = np.full(n_bins, hours * 3600.0 / n_bins)
    mu = expected_counts(cols, expo, truth, background=bkg)
    src = [float((cols.rates(k, m).sum(axis=2) * expo).sum()) for k, m in enumerate(truth)]
    chan = (cols.rates(0, truth[0]) * expo[:, None]).sum(axis=(0, 1))
    bkg_chan = bkg * expo.sum() * cols.shape[0]
    print(f"\n{hours:g} h: sources {src[0]:.0f} and {src[1]:.0f} counts, background "
          f"{mu.sum() - sum(src):.0f}; source 0 per channel {chan.min():.0f}-{chan.max():.0f}, "
          f"background per channel {bkg_chan.min():.0f}-{bkg_chan.max():.0f}")
    names = ("K", "index")
    rows = {"extracted": [], "joint": []}
    chi2, diff, times = [], [], {"extract": [], "chi2 fit": [], "joint": []}
    n_c = cols.shape[2]
    for _ in range(n):
        y = rng.poisson(mu)
        t1 = time.time()
        spec = extract_spectrum(cols, y, expo, 0)
        t2 = time.time()
        ext = fit_spectrum(spec, start[0])
        t3 = time.time()
        joint = fit_spectra(cols, y, expo, start)
        t4 = time.time()
        times["extract"].append(t2 - t1)
        times["chi2 fit"].append(t3 - t2)
        times["joint"].append(t4 - t3)
        rows["extracted"].append([(ext.model.parameters[p] - truth[0].parameters[p])
                                  / ext.errors[p] for p in names]
                                 + [ext.errors[p] for p in names])
        rows["joint"].append([(joint.models[0].parameters[p] - truth[0].parameters[p])
                              / joint.errors[0][p] for p in names]
                             + [joint.errors[0][p] for p in names])
        chi2.append(ext.statistic)
        diff.append([(ext.model.parameters[p] - joint.models[0].parameters[p])
                     / joint.errors[0][p] for p in names])
    report = {"source_counts": src, "background_counts": float(mu.sum() - sum(src)),
              "source_counts_per_channel": chan.tolist(),
              "background_counts_per_channel": bkg_chan.tolist(),
              "median_s": {k: float(np.median(v)) for k, v in times.items()}, "methods": {}}
    lo1, hi1 = wilson(round(0.6827 * n), n)
    print(f"{'method':>10} {'param':>6} {'in 1 sigma':>12} {'in 1.645':>9} {'mean pull':>10} "
          f"{'pull std':>9} {'median error':>13}   (2-sigma band at 1 sigma [{lo1:.3f}, "
          f"{hi1:.3f}])")
    for method, r in rows.items():
        r = np.array(r)
        report["methods"][method] = {}
        for j, p in enumerate(names):
            # A fit without an error (not converged, or pegged) has no pull: counted apart.
            pull = r[np.isfinite(r[:, j]), j]
            entry = {"in1": float(np.mean(np.abs(pull) < 1)),
                     "in90": float(np.mean(np.abs(pull) < 1.645)),
                     "mean_pull": float(pull.mean()), "std_pull": float(pull.std()),
                     "median_error": float(np.median(r[np.isfinite(r[:, 2 + j]), 2 + j])),
                     "no_error": int(r.shape[0] - pull.size)}
            report["methods"][method][p] = entry
            print(f"{method:>10} {p:>6} {entry['in1']:>12.3f} {entry['in90']:>9.3f} "
                  f"{entry['mean_pull']:>10.3f} {entry['std_pull']:>9.3f} "
                  f"{entry['median_error']:>13.4g}"
                  + (f"   ({entry['no_error']} fits without an error left out)"
                     if entry["no_error"] else ""))
    d = np.array(diff)
    d = d[np.all(np.isfinite(d), axis=1)]
    chi2 = np.array(chi2)
    report["difference"] = {p: {"mean": float(d[:, j].mean()), "std": float(d[:, j].std()),
                                "max_abs": float(np.abs(d[:, j]).max())}
                            for j, p in enumerate(names)}
    report["chi2"] = {"dof": n_c - 2, "mean": float(chi2.mean()), "std": float(chi2.std())}
    for j, p in enumerate(names):
        print(f"extracted - joint, {p}, in joint errors: mean {d[:, j].mean():.3f}, std "
              f"{d[:, j].std():.3f}, max |.| {np.abs(d[:, j]).max():.3f}")
    print(f"chi2 of the extracted fits: mean {chi2.mean():.1f}, std {chi2.std():.1f} for "
          f"{n_c - 2} degrees of freedom (expected {n_c - 2}, {np.sqrt(2 * (n_c - 2)):.1f})")
    print("median times (s): " + ", ".join(f"{k} {v:.2f}" for k, v in
                                            report["median_s"].items()))
    return report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="realisations")
    ap.add_argument("--photons", type=int, default=20000, help="detector MC photons per node")
    ap.add_argument("--hours", type=float, nargs="+", default=[16.7],
                    help="observations (h), one case each")
    ap.add_argument("--out", default=None, help="JSON file for the results")
    args = ap.parse_args()
    t0 = time.time()
    n_bins = 60
    # Source 0 (the one extracted) 8 deg off axis; source 1, softer, 4 deg off axis on the
    # other side.
    cols, bkg = survey(args.photons, ([8.0, 4.0], [40.0, 200.0]), n_bins)
    t_setup = time.time() - t0
    truth = [PowerLaw(2e-4, -2.0), PowerLaw(1e-4, -2.5)]
    start = [PowerLaw(4e-4, -1.6), PowerLaw(2e-4, -2.0)]
    rng = np.random.default_rng(2027)
    report = {"setup_s": t_setup, "n": args.n, "cases": {}}
    print(f"setup {t_setup:.1f} s; {args.n} realisations per case")
    for hours in args.hours:
        report["cases"][f"{hours:g} h"] = run_case(cols, bkg, truth, start, hours, args.n,
                                                   rng, n_bins)
    save(report, args.out)


if __name__ == "__main__":
    main()
