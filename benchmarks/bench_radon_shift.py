"""The Radon table's interpolation in the shadow's shift ``s``: measured error against the law.

Run ``python benchmarks/bench_radon_shift.py``; prints a markdown table recorded in
docs/response.md (output: ``benchmarks/results/bench_radon_shift.txt``).

``RadonResponse`` computes ``E(u, s, tau)`` on the offset nodes and on nodes in ``s``
(:func:`rotmod.response.radon._shift_nodes`: uniform between the kinks of ``E`` in ``s``, at
a step set by ``SHIFT_SHARE`` of the tolerance through the ``u`` law ``ERROR_LAW step^1.5``)
and interpolates every table value from them.  Here, per geometry and node step, ``E`` at 97
offsets across a period and 3000 shifts up to the geometry's largest is computed exactly and
by that interpolation; the worst difference is compared with ``ERROR_LAW step^1.5`` (the
share of the tolerance the step was set from).  Geometries: the prototype at 662 keV, the
wide field's mask, a mask thicker than its slats are wide (kinks at ``s = a, b``), small
detectors under opaque slats, a large detector under thin slats, and opaque slats with a
narrow gap whose shifts cross ``s = b`` (the strongest kink: the view through the gap
closes).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from rotmod import DetectorArray, Instrument, Mask
from rotmod.io import load_instrument
from rotmod.profiles import get_model
from rotmod.response.radon import ERROR_LAW, SHIFT_SHARE, _one_detector_values, _shift_nodes

OUT = Path(__file__).parent / "results" / "bench_radon_shift.txt"
MODEL = get_model("exact")


def cases() -> dict[str, tuple[Instrument, float | None, float]]:
    """name: (instrument, energy, largest shift in cm)."""
    return {
        "prototype, 662 keV": (load_instrument("prototype"), 662.0, 0.25),
        "wide field's mask (a = b = h = 1 cm Pb), 662 keV": (
            Instrument(Mask(1.0, 1.0, 1.0, 114.0), DetectorArray([[0.0, 0.0]], 1.0)), 662.0,
            2.4),
        "thick: a 1, b 1.3, h 3, mu 0.8": (
            Instrument(Mask(1.0, 1.3, 3.0, 60.0, mu=0.8), DetectorArray([[0.0, 0.0]], 2.0)),
            None, 1.5),
        "small detector, opaque: a 3, b 2, c 0.6": (
            Instrument(Mask(3.0, 2.0, 1.0, 150.0, mu=np.inf), DetectorArray([[0.0, 0.0]], 0.6)),
            None, 0.1),
        "big detector, thin: c 9, h 0.3, mu 0.05": (
            Instrument(Mask(2.0, 2.0, 0.3, 100.0, mu=0.05), DetectorArray([[0.0, 0.0]], 9.0)),
            None, 0.09),
        "opaque, narrow gap: a 2.87, b 0.32, c 6.84, h 2.12": (
            Instrument(Mask(2.87, 0.32, 2.12, 97.0, mu=np.inf),
                       DetectorArray([[0.0, 0.0]], 6.84)), None, 0.6),
    }


def main() -> None:
    lines = [f"load average {os.getloadavg()[0]:.2f}; SHIFT_SHARE {SHIFT_SHARE}, ERROR_LAW "
             f"{ERROR_LAW}", "",
             "| geometry | node step / R | max abs(dE) | ERROR_LAW step^1.5 | ratio |",
             "|---|---:|---:|---:|---:|"]
    print("\n".join(lines), flush=True)
    for name, (inst, energy, s_max) in cases().items():
        m, radius = inst.mask, inst.detectors.radius
        mu = m.linear_attenuation(energy)
        tau = math.inf if math.isinf(mu) else 1.2 * mu * m.thickness  # 34 deg off axis
        u = m.period * np.arange(97) / 97
        s = np.linspace(0.0, s_max, 3001)[1:]
        ref = _one_detector_values(MODEL, inst, u, s, tau, mu)
        for rel in (0.02, 0.01, 0.005, 0.002, 0.001):
            # The tolerance whose SHIFT_SHARE sets this node step.
            tol = ERROR_LAW * rel**1.5 / SHIFT_SHARE
            nodes, node0, wts = _shift_nodes(s, tol * radius**1.5, m.slat_width, m.slat_gap)
            if wts.shape[1] == 1:
                continue  # as many nodes as shifts: the values themselves
            vals = _one_detector_values(MODEL, inst, u, nodes, tau, mu)
            est = sum(wts[:, t] * vals[:, node0 + t] for t in range(wts.shape[1]))
            err = float(np.abs(est - ref).max())
            law = ERROR_LAW * rel**1.5
            line = f"| {name} | {rel:g} | {err:.2e} | {law:.2e} | {err / law:.2f} |"
            lines.append(line)
            print(line, flush=True)
    OUT.parent.mkdir(exist_ok=True)
    OUT.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
