"""Benchmark and cross-checks of rotmod.spectral.atmosphere: the tables of docs/atmosphere.md.

Run: ``PYTHONPATH=src python benchmarks/atmosphere.py`` (about 5 s on one core).  Numbers:

1. accuracy of the column integration (exponential atmosphere against its closed forms and
   scipy.quad; profile step; the fast table against direct integration);
2. what the space-weather indices, the hour and the season change at 30-40 km;
3. NRLMSIS against the US Standard Atmosphere 1976 (closed form of its defining layers);
4. the cross-check against cosi-atmosphere's published on-axis transmission at 33.6 km;
5. the transmission table 100 keV - 5 MeV x zenith 0-60 deg (and up to the horizon);
6. timing of a flight's worth of evaluations.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.integrate import quad
from scipy.special import k1e

from rotmod.spectral.atmosphere import Atmosphere, air_attenuation

# US Standard Atmosphere 1976 (NOAA-S/T 76-1562): layer bases (geopotential km), base
# temperature (K), lapse rate (K/km), base pressure (Pa); g0 M0 / R* = 34.1632 K/km,
# r0 = 6356.766 km.
_USSA76 = [(0.0, 288.15, -6.5, 101325.0), (11.0, 216.65, 0.0, 22632.06),
           (20.0, 216.65, 1.0, 5474.889), (32.0, 228.65, 2.8, 868.0187),
           (47.0, 270.65, 0.0, 110.9063), (51.0, 270.65, -2.8, 66.93887),
           (71.0, 214.65, -2.0, 3.956420)]


def ussa76_pressure(z_km: float) -> float:
    """USSA76 pressure (hPa) at geometric altitude ``z_km`` (< 86 km)."""
    hg = 6356.766 * z_km / (6356.766 + z_km)
    hb, tb, lb, pb = next(layer for layer in reversed(_USSA76) if hg >= layer[0])
    if lb == 0.0:
        return pb * np.exp(-34.1632 * (hg - hb) / tb) / 100.0
    return pb * (tb / (tb + lb * (hg - hb))) ** (34.1632 / lb) / 100.0


# cosi-atmosphere, docs/tutorials/alternative_response_representation/
# TP_33p6km_on_axis_analytical.dat (commit 7bf165c): on-axis transmission probability at
# 33.6 km, and their XCOM total attenuation (with coherent) for 78 % N2 + 22 % O2
# (cosi_atmosphere/response/data_files/mass_attenuation_coefficients_N2-78_O2-22.dat).
COSI_E_MEV = [0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0, 1.25, 1.5, 2.0, 3.0, 4.0, 5.0]
COSI_TP = [0.32533645, 0.37088378, 0.40523264, 0.45759025, 0.49672267, 0.52814659,
           0.55412672, 0.59546908, 0.62751088, 0.65915040, 0.68437334, 0.72188564,
           0.76929765, 0.79820942, 0.81766601]
COSI_MU = [1.534e-1, 1.355e-1, 1.234e-1, 1.068e-1, 9.559e-2, 8.721e-2, 8.065e-2, 7.082e-2,
           6.366e-2, 5.694e-2, 5.181e-2, 4.452e-2, 3.583e-2, 3.079e-2, 2.750e-2]


def accuracy() -> None:
    print("== 1. Column integration accuracy ==")
    H, R, rho0 = 7.0, 6371.0, 1.2e-3
    h = np.linspace(0.0, 150.0, 601)
    a = Atmosphere(h, rho0 * np.exp(-h / H), radius=R)
    worst = 0.0
    for h0 in (0.0, 30.0, 33.0, 40.0):
        r0 = R + h0
        for z in (0.0, 30.0, 60.0, 80.0, 89.0, 90.0, 92.0, 95.0):
            zr = np.radians(z)
            p = r0 * np.sin(zr)
            if z > 90.0 and p <= R:
                continue

            def f(s: float, zr: float = zr, r0: float = r0) -> float:
                return 1e5 * rho0 * np.exp(-(np.sqrt(r0**2 + s**2 + 2 * r0 * s * np.cos(zr)) - R)
                                           / H)

            s_top = np.sqrt((R + 150.0) ** 2 - p**2) - r0 * np.cos(zr)
            pts = [max(-r0 * np.cos(zr), 0.0)]
            q = sum(quad(f, lo, hi, epsabs=0, epsrel=1e-12, limit=500)[0]
                    for lo, hi in zip([0.0, *pts], [*pts, s_top], strict=True) if hi > lo)
            worst = max(worst, abs(a.column_depth_exact(h0, z) / q - 1))
    print(f"exponential atmosphere (H = 7 km), ours vs scipy.quad, h 0-40 km, z 0-95 deg: "
          f"max |rel| = {worst:.1e}")
    for h0 in (0.0, 33.0):
        x = (R + h0) / H
        ratio = a.column_depth_exact(h0, 90.0) / a.column_depth_exact(h0, 0.0)
        print(f"  h = {h0:4.1f} km: X(90)/X(0) = {ratio:.6f}, x e^x K1(x) = {x * k1e(x):.6f}, "
              f"sqrt(pi x / 2) = {np.sqrt(np.pi * x / 2):.6f}")
    ref = Atmosphere.from_msis(step=0.05)
    rng = np.random.default_rng(1)
    hh, zz = rng.uniform(25.0, 45.0, 300), rng.uniform(0.0, 90.0, 300)
    xr = ref.column_depth_exact(hh, zz)
    for step in (0.25, 0.5, 1.0):
        xs = Atmosphere.from_msis(step=step).column_depth_exact(hh, zz)
        print(f"NRLMSIS profile step {step:4.2f} km vs 0.05 km, h 25-45 km, z 0-90: "
              f"max |rel| = {np.max(np.abs(xs / xr - 1)):.1e}")
    a = Atmosphere.from_msis()
    for lo, hi, zlo, zhi in ((0, 60, 0, 90), (25, 45, 80, 90), (25, 45, 90, 96)):
        hh, zz = rng.uniform(lo, hi, 400), rng.uniform(zlo, zhi, 400)
        xe, xt = a.column_depth_exact(hh, zz), a.column_depth(hh, zz)
        ok = np.isfinite(xe)
        assert np.array_equal(ok, np.isfinite(xt))
        print(f"table vs direct, h {lo}-{hi} km, z {zlo}-{zhi} deg: max |rel| = "
              f"{np.max(np.abs(xt[ok] / xe[ok] - 1)):.1e} ({(~ok).sum()} rays hit the ground)")


def variability() -> None:
    print("\n== 2. Vertical column X(h, 0) (g/cm2) at Fort Sumner: indices, hour, season ==")
    hs = (30.0, 33.0, 36.0, 40.0)
    base = Atmosphere.from_msis().column_depth_exact(hs, 0.0)
    print("case                              " + "".join(f"{h:>9.0f} km" for h in hs))
    print("default (2025-09-15 18 UT, 150/150/4)" + "".join(f"{x:12.4f}" for x in base))
    cases = {
        "F10.7 = F10.7a = 70, Ap = 4": {"f107": 70.0, "f107a": 70.0},
        "F10.7 = F10.7a = 250, Ap = 4": {"f107": 250.0, "f107a": 250.0},
        "Ap = 100 (storm)": {"ap": 100.0},
        "06 UT (local midnight)": {"date": "2025-09-15T06:00"},
        "2025-01-15 18 UT (winter)": {"date": "2025-01-15T18:00"},
        "2025-07-15 18 UT (summer)": {"date": "2025-07-15T18:00"},
        "Palestine TX (31.8 N)": {"latitude": 31.78, "longitude": -95.72},
        "Wanaka NZ (44.7 S), 2016-05-17": {"latitude": -44.72, "longitude": 169.25,
                                          "date": "2016-05-17T00:00"},
        "McMurdo (77.9 S), 2025-12-20": {"latitude": -77.85, "longitude": 166.67,
                                        "date": "2025-12-20T00:00"},
    }
    for name, kw in cases.items():
        x = Atmosphere.from_msis(**kw).column_depth_exact(hs, 0.0)
        print(f"{name:36s}" + "".join(f"{v / b - 1:+12.2e}" for v, b in zip(x, base,
                                                                              strict=True)))


def standard_atmosphere() -> None:
    print("\n== 3. NRLMSIS (Fort Sumner, default date) vs US Standard Atmosphere 1976 ==")
    a = Atmosphere.from_msis()
    print("  h km   P_USSA76 hPa   P_MSIS hPa   ratio   X_MSIS g/cm2   X*g/P-1   2H_p/R")
    lat = np.radians(a.info["latitude"])
    gs = 9.7803253359 * (1 + 0.00193185265241 * np.sin(lat) ** 2) / np.sqrt(
        1 - 0.00669437999013 * np.sin(lat) ** 2)
    for h in (30.0, 32.0, 33.0, 34.0, 35.0, 40.0):
        i = int(np.searchsorted(a.altitude, h))
        g = gs * (a.radius / (a.radius + h)) ** 2
        x = float(a.column_depth_exact(h, 0.0))
        pm = a.pressure[i]
        # pressure scale height kT/(m g) with the column's mean molecular mass ~ P/(X g) ...
        hp = 8.314462618 * 1e-3 * _temperature(a, h) / (28.9644e-3 * g)
        print(f"{h:6.1f} {ussa76_pressure(h):12.3f} {pm:12.3f} {pm / ussa76_pressure(h):8.4f} "
              f"{x:12.4f} {x * 10 * g / (pm * 100) - 1:11.2e} {2 * hp / a.radius:9.2e}")


def _temperature(a: Atmosphere, h: float) -> float:
    """Temperature (K) from the profile: T = P m / (rho k) with the mean molecular mass of air."""
    i = int(np.searchsorted(a.altitude, h))
    return a.pressure[i] * 100 * 28.9644e-3 / (a.density[i] * 1e3 * 8.314462618)


def cosi() -> None:
    print("\n== 4. Cross-check: cosi-atmosphere on-axis transmission at 33.6 km ==")
    e_kev = np.array(COSI_E_MEV) * 1e3
    tp = np.array(COSI_TP)
    x_cosi = -np.log(tp) / np.array(COSI_MU)
    print(f"their implied column -ln(TP)/mu: {x_cosi.mean():.4f} g/cm2 "
          f"(spread {np.ptp(x_cosi):.1e} over energies)")
    site = Atmosphere.from_msis("2016-06-13T12:00", -5.66, -107.38)  # their tutorial's inputs
    fs = Atmosphere.from_msis()
    xs = float(site.column_depth(33.6, 0.0))
    xf = float(fs.column_depth(33.6, 0.0))
    print(f"ours, their tutorial's site and date (2016-06-13 12 UT, -5.66, -107.38): "
          f"X = {xs:.4f} g/cm2;  Fort Sumner default: X = {xf:.4f} g/cm2")
    # Their column estimator (TPCalc.los_integral): a left Riemann sum in 100 m steps along
    # the line of sight, R_E = 6378 km, up to 200 km; here on our NRLMSIS profile.  For a
    # density falling with scale height H it overestimates by ~dx / (2 H) = 0.7 %.
    print("zenith deg   ours X     their estimator on our profile   ratio")
    zens = (0.0, 20.0, 40.0, 60.0)
    theirs_x = []
    for zen in zens:
        z = np.radians(zen)
        s = np.arange(0.0, 2000.0, 0.1)
        hs = np.sqrt((6378.0 + 33.6) ** 2 + s**2 + 2 * (6378.0 + 33.6) * s * np.cos(z)) - 6378.0
        riemann = 1e4 * site.density_at(np.minimum(hs[hs < 150.0], 150.0)).sum()
        theirs_x.append(riemann)
        ours = float(site.column_depth(33.6, zen))
        print(f"{zen:8.0f} {ours:10.4f} {riemann:20.4f} {riemann / ours:22.5f}")
    print("T at 33.6 km, their site and date: ours / their method (their mu, their column)")
    print("  E keV " + "".join(f"{z:>17.0f} deg" for z in zens))
    for k in (0, 5, 8, 14):
        row = [f"{float(site.transmission(e_kev[k], z, 33.6)):.4f} / "
               f"{np.exp(-COSI_MU[k] * xt):.4f}" for z, xt in zip(zens, theirs_x, strict=True)]
        print(f"{e_kev[k]:7.0f} " + "".join(f"{r:>21s}" for r in row))
    mu = air_attenuation(e_kev)
    t_site = site.transmission(e_kev, 0.0, 33.6)
    t_fs = fs.transmission(e_kev, 0.0, 33.6)
    print("  E keV  mu_ours  mu_cosi   T_cosi   T_ours(site)  diff    T_ours(FS)   diff")
    for k, e in enumerate(e_kev):
        print(f"{e:7.0f} {mu[k]:8.5f} {COSI_MU[k]:8.5f} {tp[k]:8.4f} {t_site[k]:11.4f} "
              f"{t_site[k] - tp[k]:+8.4f} {t_fs[k]:11.4f} {t_fs[k] - tp[k]:+8.4f}")


def table() -> None:
    print("\n== 5. Transmission of the direct beam, Fort Sumner default, 33 km ==")
    a = Atmosphere.from_msis()
    zen = np.array([0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 85.0, 90.0])
    x = a.column_depth(33.0, zen)
    print("zenith deg      " + "".join(f"{z:8.0f}" for z in zen))
    print("X g/cm2         " + "".join(f"{v:8.2f}" for v in x))
    print("X cos z / X(0)  " + "".join(f"{v * np.cos(np.radians(z)) / x[0]:8.4f}"
                                      for v, z in zip(x, zen, strict=True)))
    for e in (100.0, 200.0, 300.0, 511.0, 1000.0, 2000.0, 5000.0):
        t = a.transmission(e, zen, 33.0)
        print(f"T({e:5.0f} keV)     " + "".join(f"{v:8.4f}" for v in t))


def timing() -> None:
    print("\n== 6. Timing ==")
    t0 = time.perf_counter()
    a = Atmosphere.from_msis()
    t1 = time.perf_counter()
    a.column_depth(33.0, 0.0)
    t2 = time.perf_counter()
    rng = np.random.default_rng(2)
    n = 1_000_000
    h, z = rng.uniform(30.0, 40.0, n), rng.uniform(0.0, 95.0, n)
    t3 = time.perf_counter()
    a.column_depth(h, z)
    t4 = time.perf_counter()
    print(f"NRLMSIS profile 0-150 km: {t1 - t0:.3f} s; column table: {t2 - t1:.3f} s; "
          f"1e6 (h, z) look-ups: {t4 - t3:.3f} s")


if __name__ == "__main__":
    accuracy()
    variability()
    standard_atmosphere()
    cosi()
    table()
    timing()
