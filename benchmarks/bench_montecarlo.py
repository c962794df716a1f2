"""Monte Carlo speed: photons per second on one core and on all, numba vs plain numpy.

Also times the paper's standard: a response with signal-to-noise 10 per time bin, 560 time
bins, 4900 sky bins (14 deg field in 12' bins), one detector.  SNR 10 per bin needs 100
transmitted photons per (time bin, sky bin) (Poisson: SNR = sqrt(k)); at the mean
transmission P of the a = b = c mask (about 1/2) that is 100 / P incident photons per cell,
i.e. about 200 x 560 x 4900 = 5.5e8 photons in all.  The paper quotes 1.3 days for it.

    python benchmarks/bench_montecarlo.py
"""

from __future__ import annotations

import statistics
import time

import numba
import numpy as np

from rotmod import Instrument
from rotmod.materials import PAPER_SIGMA_662
from rotmod.montecarlo import simulate_profiles

# The paper preset (lead, a = b = c = 4 cm, h = 2 cm, L = 100 cm) with its fixed sigma.
INST = Instrument.paper(sigma=PAPER_SIGMA_662)
THETA, PHI = [6.0], [32.0]  # deg (a plain public angle means degrees)
XI = (np.arange(560) + 0.5) * 360.0 / 560  # deg


def numpy_transport(inst, theta, phi, xi, n_per_angle, rng):
    """The same analog transport, vectorised with plain numpy (one angle at a time)."""
    m = inst.mask
    a, b, L, h = m.slat_width, m.slat_gap, m.height, m.thickness
    mu = m.linear_attenuation()
    p = a + b
    R = inst.detectors.radius
    x0, y0 = inst.detectors.positions[0]
    l_bot, l_top = L / np.cos(theta), (L + h) / np.cos(theta)
    counts = np.empty(xi.size, np.int64)
    for t, x in enumerate(xi):
        c, s = np.cos(x), np.sin(x)
        e = rng.uniform(-1, 1, size=(int(1.3 * n_per_angle) + 64, 2))
        e = e[np.einsum("ij,ij->i", e, e) <= 1.0][:n_per_angle]
        px, py = x0 + R * e[:, 0], y0 + R * e[:, 1]
        u0 = px * c - py * s
        du = np.sin(theta) * np.cos(phi + x)
        ub, ut = u0 + du * l_bot, u0 + du * l_top
        umin, umax = np.minimum(ub, ut), np.maximum(ub, ut)
        k_lo = np.ceil((umin - b / 2 - a) / p)
        k_hi = np.floor((umax - b / 2) / p)
        chord = np.zeros(u0.size)
        for j in range(int(np.max(k_hi - k_lo)) + 1):
            k = k_lo + j
            e1 = b / 2 + k * p
            l1, l2 = (e1 - u0) / du, (e1 + a - u0) / du
            lo = np.maximum(np.minimum(l1, l2), l_bot)
            hi = np.minimum(np.maximum(l1, l2), l_top)
            chord += np.where(k <= k_hi, np.maximum(hi - lo, 0.0), 0.0)
        counts[t] = np.count_nonzero(rng.random(u0.size) < np.exp(-mu * chord))
    return counts


def _median_rate(fn, n_photons, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return n_photons / statistics.median(times)


def main() -> None:
    n_threads = numba.config.NUMBA_NUM_THREADS
    simulate_profiles(INST, THETA, PHI, XI[:4], n_photons=1000, seed=0)  # compile / load
    n_cell = 50_000
    total = n_cell * XI.size
    rows = []
    for k in sorted({1, n_threads}):
        numba.set_num_threads(k)
        rate = _median_rate(
            lambda: simulate_profiles(INST, THETA, PHI, XI, n_photons=n_cell, seed=1),
            total, 5,
        )
        rows.append((f"numba, {k} thread{'s' if k > 1 else ''}", rate))
    numba.set_num_threads(n_threads)
    rng = np.random.default_rng(1)
    n_np = 2000
    rate_np = _median_rate(
        lambda: numpy_transport(INST, *np.radians([THETA[0], PHI[0]]), np.radians(XI), n_np, rng),
        n_np * XI.size, 3
    )
    rows.append(("numpy (vectorised, 1 core)", rate_np))
    print(f"{'implementation':32s} {'photons/s':>12s}  (median; {total:.2g} photons per run)")
    for name, r in rows:
        print(f"{name:32s} {r:12.3g}")

    # The paper's standard: 4900 sky bins x 560 time bins, SNR 10 per bin.
    nx = 70  # 70 x 70 = 4900 sky bins
    pix = 12.0 / 60.0
    c = (np.arange(nx) - (nx - 1) / 2) * pix
    gx, gy = np.meshgrid(c, c)
    theta = np.degrees(np.arctan(np.radians(np.hypot(gx, gy)))).ravel()  # deg
    phi = np.degrees(np.arctan2(gy, gx)).ravel()
    probe = simulate_profiles(INST, theta[::97], phi[::97], XI, n_photons=2000, seed=2)
    pbar = float(probe.fraction.mean())
    n_inc = int(np.ceil(100.0 / pbar))
    n_total = n_inc * XI.size * theta.size
    t0 = time.perf_counter()
    res = simulate_profiles(INST, theta, phi, XI, n_photons=n_inc, seed=3)
    dt = time.perf_counter() - t0
    snr = np.sqrt(res.counts.mean())
    print(
        f"\npaper standard: mean transmission {pbar:.3f} -> {n_inc} photons per cell, "
        f"{n_total:.3g} photons; {dt:.1f} s on {n_threads} threads "
        f"({n_total / dt:.3g} photons/s; mean SNR per bin {snr:.1f}); paper: 1.3 days "
        f"= {1.3 * 86400:.0f} s, {1.3 * 86400 / dt:.0f} x slower"
    )


if __name__ == "__main__":
    main()
