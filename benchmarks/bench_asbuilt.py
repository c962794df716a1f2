"""Speed of the exact model of the instrument as built on its common cases.

Run ``NUMBA_NUM_THREADS=1 python benchmarks/bench_asbuilt.py [--repeat 3]`` (warm: the
kernels are compiled, or loaded from the cache, before the timed calls).

* ``flat 2 m``: the prototype's 19 flat faces, its mask tilted by 0.2 deg and offset by
  1 mm, 300 sources 2 m away, 360 mask angles (2.05e6 points), 662 keV.
* ``thick inf``: the lab prototype (2.5 cm NaI), same mask, 50 sources at infinity,
  360 angles, 662 keV.
* ``thick 2 m``: the lab prototype, 12 sources 2 m away, 36 angles, 662 keV.

Times are the best of ``--repeat`` (the machine is shared); results in docs/physics.md
("The instrument as built").
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from rotmod import Instrument, get_model
from rotmod.io import load_instrument


def _cases():
    rng = np.random.default_rng(5)
    proto, lab = load_instrument("prototype"), load_instrument("prototype-lab")
    mask = dataclasses.replace(proto.mask, tilt_x=0.2, axis_offset_x=0.1)
    flat = Instrument(mask, proto.detectors)
    thick = Instrument(mask, lab.detectors)
    th, ph = rng.uniform(0, 10, 300), rng.uniform(0, 360, 300)
    xi = np.arange(360.0)
    return [
        ("flat 2 m", flat, th, ph, xi, {"energy": 662.0, "distance": 200.0}),
        ("thick inf", thick, th[:50], ph[:50], xi, {"energy": 662.0}),
        ("thick 2 m", thick, th[:12], ph[:12], xi[::10], {"energy": 662.0, "distance": 200.0}),
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    model = get_model("exact")
    print(f"{'case':<10} {'points':>9} {'best s':>8} {'us/point':>9}")
    for name, inst, th, ph, xi, kw in _cases():
        model.profile(inst, th[:1], ph[:1], xi[:2], **kw)  # compile / load
        best = np.inf
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            P = model.profile(inst, th, ph, xi, **kw)
            best = min(best, time.perf_counter() - t0)
        print(f"{name:<10} {P.size:>9d} {best:>8.2f} {best / P.size * 1e6:>9.2f}", flush=True)


if __name__ == "__main__":
    main()
