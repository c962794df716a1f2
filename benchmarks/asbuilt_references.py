"""The exact model of the instrument as built against the brute-force references.

Run ``python benchmarks/asbuilt_references.py`` (from the repository root: it imports
``tests/profiles/_brute.py``; ~6 min).  For each group of hard geometries it prints the
largest ``|model - reference|`` over the group's points, the reference being rays traced
from first principles through the tilted slat slab and fine quadrature over the face or the
detector's volume (tests/profiles/_brute.py; quadrature orders 30 for flat faces, 32 for
thick detectors at infinity and 48 near a source: their changes from orders 20, 24 and 32
bound their own errors, < 1e-12, < 2e-10 and < 1.5e-9).  Results in docs/physics.md ("The
instrument as built").
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.profiles._brute import flat_profile, thick_profile

from rotmod import DetectorArray, Instrument, Mask, Material, get_model
from rotmod.io import load_instrument

_NAI = Material("NaI", density=3.67)
_PB103 = Material("Pb", density=11.34, mass_attenuation=0.103)


def _groups():
    proto = load_instrument("prototype").mask
    xi = (7.0, 67.0, 131.0, 200.0, 263.0, 333.0)
    src = ((2.0, 30.0), (8.0, 200.0), (15.0, -60.0))
    out = []
    for tilt in (0.2, 0.5, 1.0, 2.0):
        m = dataclasses.replace(proto, tilt_x=0.8 * tilt, tilt_y=-0.6 * tilt, axis_offset_x=0.3)
        inst = Instrument(m, DetectorArray.single(3.8, 4.0, -2.5))
        out.append((f"flat, prototype, 2 m, tilt {tilt} deg", inst, 200.0, None, src, xi))
    for tilt in (0.5, 1.0, 2.0):
        m = Mask(3.8, 3.8, 2.0, 50.0, "Pb", tilt_x=tilt, tilt_y=0.3 * tilt, axis_offset_y=-0.5)
        inst = Instrument(m, DetectorArray.single(3.8, 6.0, 3.0))
        out.append((f"flat, L = 50 cm, 1 m, tilt {tilt} deg", inst, 100.0, None, src, xi))
    thick5 = Instrument(Mask(3.8, 3.8, 2.0, 114.55, _PB103),
                        DetectorArray([[3.1, -1.2]], 3.8, 5.0, _NAI))
    for e in (122.0, 662.0):
        out.append((f"5 cm NaI, 40 deg, infinity, {e:g} keV", thick5, None, e,
                    ((40.0, 30.0), (40.0, -20.0)), (10.0, 70.0)))
    for tilt in (0.0, 1.0, -1.5):
        m = Mask(3.8, 3.8, 2.0, 114.55, "Pb", tilt_x=tilt, tilt_y=-0.5 * tilt, axis_offset_x=0.2)
        inst = Instrument(m, DetectorArray([[4.0, -2.5]], 3.8, 2.5, _NAI))
        for e in (122.0, 662.0):
            out.append((f"2.5 cm NaI, 2 m, tilt {tilt} deg, {e:g} keV", inst, 200.0, e,
                        ((8.0, 200.0), (15.0, -60.0), (25.0, 60.0)), (40.0, 100.0, 300.0)))
    m = Mask(3.8, 3.8, 2.0, 50.0, "Pb", tilt_x=1.0, tilt_y=0.3, axis_offset_y=-0.5)
    inst = Instrument(m, DetectorArray([[6.0, 3.0]], 3.8, 2.5, _NAI))
    out.append(("2.5 cm NaI, L = 50 cm, 1 m, tilt 1 deg, 662 keV", inst, 100.0, 662.0,
                ((8.0, 200.0), (15.0, -60.0)), (40.0, 300.0)))
    return out


def main() -> None:
    model = get_model("exact")
    print(f"{'group':<48} {'points':>6} {'max |model - ref|':>18} {'s':>6}")
    for name, inst, D, e, src, xi in _groups():
        t0 = time.perf_counter()
        worst = 0.0
        npts = 0
        for th, ph in src:
            P = model.profile(inst, [th], [ph], list(xi), energy=e or 662.0, distance=D)
            for k, x in enumerate(xi):
                if inst.detectors.is_flat:
                    ref = flat_profile(inst, th, ph, x, distance=D, energy=e or 662.0, n=30)
                else:
                    ref = thick_profile(inst, th, ph, x, distance=D, energy=e,
                                        n=32 if D is None else 48)
                worst = max(worst, abs(float(P[0, k, 0]) - ref))
                npts += 1
        print(f"{name:<48} {npts:>6d} {worst:>18.2e} {time.perf_counter() - t0:>6.1f}",
              flush=True)


if __name__ == "__main__":
    main()
