"""What the seed paper claims, stated once: the report puts rotmod's results beside these.

Budden, Budden, Case & Cherry, *Characteristic Count Rate Profiles for a Rotating Modulator
Gamma-Ray Imager*: the IDL timings of Sec. 4.2, the statements attached to Figs. 4-11 and the
lab prototype's two-source result (Sec. 4.3).
"""

from __future__ import annotations

__all__ = [
    "IMAGE_CLAIMS", "MONTE_CARLO", "OUTSIDE", "PAPER_SPEED_S", "PROFILE_CLAIMS", "PROTO_CLAIM",
    "SPEED_LABEL",
]

#: The speed table's key of the Monte Carlo (the other keys are profile models' names).
MONTE_CARLO = "montecarlo"

#: The paper's IDL timings for one detector, 4900 sky bins x 560 time bins (s), by profile
#: model (plus the Monte Carlo), in the table's order.
PAPER_SPEED_S = {
    "standard": 0.8,
    "advanced-g0": 2.6,
    "advanced-approx": 5.4,
    "exact": None,
    MONTE_CARLO: 1.3 * 86400.0,
}
SPEED_LABEL = {
    "standard": "standard",
    "advanced-g0": "advanced, G0 only",
    "advanced-approx": "advanced, G0 + G1~",
    "exact": "exact (not in the paper)",
    MONTE_CARLO: "Monte Carlo (SNR 10 per time bin)",
}

#: What the paper says about each validation scenario.
PROFILE_CLAIMS = {
    "thick20": "Fig. 4: the MC profile is asymmetric (shadow lengthening); the standard formula "
               "cannot describe it; the advanced profile is 'virtually identical' to the MC.",
    "wide50": "Fig. 5: asymmetric envelope and reduced contrast (transmission through a 1 cm "
              "mask); the standard formula describes neither; the advanced one does.",
    "gap12": "Fig. 6: b = 12 cm: the advanced profile shows the expected saturation of the "
             "transmission several times per rotation (standard not applicable).",
    "slat12": "Fig. 7: a = 12 cm: the advanced formula describes the intervals of zero "
              "transmission ('dead time') (standard not applicable).",
    "det12": "Fig. 8: c = 12 cm: up to two slats shadow the detector at once, described by the "
             "advanced formula (standard not applicable).",
    "thin5mm": "Fig. 10 set-up: 55 % transmission through 5 mm slats at 662 keV, accounted for "
               "by the advanced formula, not by the standard one.",
    "zen48": "Fig. 11 set-up: at 48 deg many photons clip the slats; the standard formula "
             "does not account for it.",
}
OUTSIDE = ("Outside the advanced formula's validity (Sec. 3.4: requires a, b >= h tan "
            "theta); the paper has no model here. rotmod's exact model should match the MC.")

IMAGE_CLAIMS = {
    "a": "Fig. 9: 122 keV source near the axis, 2 cm mask (opaque): the standard and "
         "advanced responses both reconstruct the source accurately.",
    "b": "Fig. 10: 662 keV, 5 mm mask (55 % slat transmission): the standard response "
         "reconstructs spurious peaks; the advanced one does not.",
    "c": "Fig. 11: 662 keV at theta ~ 48 deg, 2 cm mask: the standard response gives "
         "spurious peaks and no source at the true location; the advanced one finds the "
         "source 'virtually free of noise'.",
}
PROTO_CLAIM = ("Sec. 4.3 (citing Budden et al. 2010): the 19-detector prototype (b/L = "
                "1.9 deg) resolves two point sources 35' apart in the presence of background "
                "(super-resolution, with NCAR).")
