"""One file of every FITS product kind rotmod writes, for the checks that every product must
pass (fitsverify, provenance): event lists with and without a pointing, folded profiles, and
images on each grid kind."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rotmod.events import fold
from rotmod.io import write_events, write_folded
from rotmod.io.images import write_image
from rotmod.montecarlo import simulate_observation
from rotmod.reconstruction import reconstruct
from rotmod.sky import Attitude, CelestialGrid, HealpixGrid, PointSources, SkyGrid
from rotmod.testing import MatrixOperator, tiny_instrument
from tests.conftest import rad

#: What the products below are written with: a seed and a command long enough to need
#: CONTINUE cards.
SEED = 8
COMMAND = ["rotmod", "simulate", "--seed", str(SEED), "--out", "a/" * 50 + "events.fits"]


def write_products(folder: Path, **provenance) -> dict[str, Path]:
    """Write one product of each kind into ``folder``; ``provenance`` goes to every writer."""
    inst = tiny_instrument(diameter=3.8, rotation_period=30.0)
    src = PointSources([6.0, 12.0], rad([0.3, 2.0]), rate=[40.0, 10.0], energy=662.0)
    ev = simulate_observation(inst, src, t_stop=40.0, background=2.0, seed=SEED)
    pointed = simulate_observation(inst, src, t_stop=40.0, seed=SEED,
                                   attitude=Attitude(10.0, 20.0, 30.0))
    grid = SkyGrid((6, 8), 0.5, center=(10.0, -3.0))
    rng = np.random.default_rng(0)
    R = MatrixOperator(rng.uniform(0, 1, (2, 30, grid.size)), grid)
    y = rng.poisson(5.0 * (R.forward(np.ones(grid.size)) + 1.0))
    res = reconstruct(R, y, "mlem", exposure=5.0, background=1.0, max_iter=3)
    meta = {"EXPOSURE": 40.0, "E_MIN": 600.0, "E_MAX": 700.0}
    cel = CelestialGrid((5, 7), 0.5, 10.0, 20.0, Attitude(10.0, 20.0, 0.0))
    hpx = HealpixGrid(16, 300.0, 40.0, 12.0, Attitude(300.0, 40.0, -15.0), "ring")
    return {
        "events": write_events(ev, folder / "ev.fits", **provenance),
        "pointed events": write_events(pointed, folder / "ev_pnt.fits", **provenance),
        "folded": write_folded(fold(ev, 24, energy_band=(600, 700)), folder / "folded.fits",
                               **provenance),
        "instrument image": write_image(folder / "img.fits", res, meta=meta, **provenance),
        "celestial image": write_image(folder / "cel.fits", image=rng.random(cel.shape),
                                       grid=cel, uncertainty=rng.random(cel.shape), meta=meta,
                                       **provenance),
        "healpix image": write_image(folder / "hpx.fits", image=rng.random(hpx.shape),
                                     grid=hpx, uncertainty=rng.random(hpx.shape), meta=meta,
                                     **provenance),
    }


@pytest.fixture(scope="module")
def products(tmp_path_factory) -> dict[str, Path]:
    """Every product kind, written with a seed and a (long) command."""
    return write_products(tmp_path_factory.mktemp("products"), seed=SEED, command=COMMAND)
