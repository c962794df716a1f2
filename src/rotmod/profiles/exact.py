"""The exact characteristic profile, valid for every geometry (model notes in
:mod:`rotmod.profiles._exact_kernels`; the instrument as built in
:mod:`rotmod.profiles._asbuilt`; docs/physics.md)."""

from __future__ import annotations

import numpy as np

from rotmod.geometry import Instrument
from rotmod.profiles._asbuilt import evaluate as as_built
from rotmod.profiles._exact_kernels import _exact_grid, exact_point, point_edges
from rotmod.profiles.base import ProfileModel, ProjectedGeometry, register_model

__all__ = ["ExactModel", "exact_point", "point_edges"]


#: Sources per kernel call (bounds the row kernel's scratch to ~16 MB per thread).
_SOURCE_CHUNK = 1 << 15


@register_model("exact")
class ExactModel(ProfileModel):
    """Exact profile from first principles, valid for every geometry (notes in ``_exact_kernels``).

    Clip pieces are integrated by Gauss–Legendre quadrature: accurate to 1e-10 (better than
    1e-12 measured against brute-force quadrature, tests/profiles/test_exact.py).  Instruments as
    built (axis offset and tilt, slat patterns, finite outlines, ...) take
    :mod:`rotmod.profiles._asbuilt` (docs/physics.md, "The instrument as built").
    """

    handles_as_built = True

    def evaluate(
        self,
        instrument: Instrument,
        geom: ProjectedGeometry,
        cos_xi: np.ndarray,
        sin_xi: np.ndarray,
        out: np.ndarray,
    ) -> None:
        if not instrument.is_ideal or not geom.at_infinity:
            # The instrument as built: offsets, tilts, slat patterns, outlines, sources at a
            # finite distance.
            as_built(instrument, geom, cos_xi, sin_xi, out)
            return
        m = instrument.mask
        args = (instrument.detectors.radius, m.slat_width, m.slat_gap)
        nn = out.shape[2]
        if nn <= _SOURCE_CHUNK:
            _exact_grid(geom.X, geom.Y, geom.Sx, geom.Sy, geom.tau, cos_xi, sin_xi, *args, out)
            return
        # The row kernel's scratch grows with the sources per call (15 x 2 n_slats float64
        # per source and thread): bound it by evaluating slices of sources.
        c = np.ascontiguousarray
        for n0 in range(0, nn, _SOURCE_CHUNK):
            n1 = min(nn, n0 + _SOURCE_CHUNK)
            part = np.empty((*out.shape[:2], n1 - n0), dtype=out.dtype)
            _exact_grid(
                c(geom.X[:, n0:n1]), c(geom.Y[:, n0:n1]), geom.Sx[n0:n1], geom.Sy[n0:n1],
                geom.tau[n0:n1], cos_xi, sin_xi, *args, part,
            )
            out[:, :, n0:n1] = part

