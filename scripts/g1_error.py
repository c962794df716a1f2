"""Error of the paper's G1~ approximation against the exact G1 over the paper's scenarios.

Prints a markdown table (used in docs/physics.md).  Lead mask, rho = 11.34 g/cm3,
sigma = 0.103 cm2/g (662 keV), L = 100 cm; 720 mask angles per rotation; two detectors
(on the axis and at (4.2, 0) cm, the neighbour in the 19-detector prototype); azimuths
phi = 0, 45 and 135 deg.  G1 = P_advanced - P_g0 (summed over slats), G1~ = P_approx - P_g0.

Run: ``python scripts/g1_error.py``.
"""

from __future__ import annotations

import numpy as np

from rotmod.errors import ModelValidityError
from rotmod.geometry import DetectorArray, Instrument
from rotmod.materials import PAPER_SIGMA_662
from rotmod.profiles import get_model

# (label, a, b, c, h, theta_deg)
SCENARIOS = [
    ("Fig. 4: a=b=c=4, h=20, θ=6°", 4.0, 4.0, 4.0, 20.0, 6.0),
    ("Fig. 5: a=b=c=4, h=1, θ=50°", 4.0, 4.0, 4.0, 1.0, 50.0),
    ("Fig. 6: b=12 (a=c=4), h=2, θ=10°", 4.0, 12.0, 4.0, 2.0, 10.0),
    ("Fig. 7: a=12 (b=c=4), h=2, θ=10°", 12.0, 4.0, 4.0, 2.0, 10.0),
    ("Fig. 8: c=12 (a=b=4), h=2, θ=10°", 4.0, 4.0, 12.0, 2.0, 10.0),
    ("Fig. 10: 5 mm mask, a=b=c=4, θ=3°", 4.0, 4.0, 4.0, 0.5, 3.0),
    ("Fig. 11: 2 cm mask, a=b=c=4, θ=48°", 4.0, 4.0, 4.0, 2.0, 48.0),
    ("thick: a=b=c=4, h=20, θ=12°", 4.0, 4.0, 4.0, 20.0, 12.0),
]
PHI_DEG = (0.0, 45.0, 135.0)
N_ANGLES = 720


def scenario_errors(a: float, b: float, c: float, h: float, theta_deg: float) -> dict[str, float]:
    """Max/RMS of |P_approx - P_exact| and related sizes, over detectors, azimuths, angles."""
    inst = Instrument.paper(a=a, b=b, c=c, h=h, sigma=PAPER_SIGMA_662)
    inst = Instrument(inst.mask, DetectorArray([[0.0, 0.0], [4.2, 0.0]], c))
    theta = np.full(len(PHI_DEG), theta_deg)  # deg
    phi = np.asarray(PHI_DEG)
    xi = np.linspace(0, 360.0, N_ANGLES, endpoint=False)
    p_ex = get_model("advanced").profile(inst, theta, phi, xi)
    p_ap = get_model("advanced-approx").profile(inst, theta, phi, xi)
    p_g0 = get_model("advanced-g0").profile(inst, theta, phi, xi)
    p_exact = get_model("exact").profile(inst, theta, phi, xi)
    err = p_ap - p_ex
    g1 = p_ex - p_g0
    return {
        "max": float(np.max(np.abs(err))),
        "rms": float(np.sqrt(np.mean(err**2))),
        "g1_max": float(np.max(g1)),
        "rel": float(np.max(np.abs(err)) / max(float(np.max(g1)), 1e-300)),
        "g0_max": float(np.max(np.abs(p_g0 - p_ex))),
        "adv_vs_exact": float(np.max(np.abs(p_ex - p_exact))),
    }


def main() -> None:
    """Print the markdown table."""
    print("| scenario | h tanθ (cm) | max \\|G1~−G1\\| | RMS \\|G1~−G1\\| | max G1 "
          "| max err / max G1 | max \\|P_G0−P\\| (no G1) | max \\|advanced−exact\\| |")
    print("|---|---|---|---|---|---|---|---|")
    for label, a, b, c, h, th in SCENARIOS:
        smax = h * np.tan(np.radians(th))
        try:
            r = scenario_errors(a, b, c, h, th)
        except ModelValidityError:
            print(f"| {label} | {smax:.2f} | outside the advanced model's validity "
                  f"(min(a, b) = {min(a, b):g} cm < h tanθ): use the exact model | | | | | |")
            continue
        print(f"| {label} | {smax:.2f} | {r['max']:.2e} | {r['rms']:.2e} | {r['g1_max']:.2e} "
              f"| {r['rel']:.2f} | {r['g0_max']:.2e} | {r['adv_vs_exact']:.1e} |")


if __name__ == "__main__":
    main()
