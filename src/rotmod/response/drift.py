"""The response of an observation whose pointing drifts: the exposure-weighted sum.

A balloon gondola drifts and turns; over an attitude interval ``k`` (short enough for the
attitude to be constant) a sky pixel ``n`` lies at its own instrument direction, so its
profile is ``P_k[d, t, n]``.  The counts folded over the whole observation are, bin by bin,
the sum over intervals of ``exposure_k[t] P_k[d, t, n] S[n]``, so the response the folded
data see is

    P[d, t, n] = sum_k exposure_k[t] P_k[d, t, n] / sum_k exposure_k[t],

with ``exposure_k[t]`` the time interval ``k`` spends in mask-angle bin ``t`` (the same exact
per-bin exposure that folding uses).  It is a response like any other, on a celestial grid:
with ``operator="matrix"`` the sum is computed and held (a
:class:`~rotmod.response.MaterialisedResponse`); with ``operator="radon"`` it is a
:class:`RadonDriftResponse`, which is what a wide field needs: no ``n_det n_time n_sky``
matrix, ONE table of the exact profile for every interval (it depends on the instrument,
energy, tolerance and the range of pixel zeniths only), and products whose cost follows the
bins the flight sweeps, almost independent of the number of intervals
(``docs/physics.md``, section 2c):

* each interval's instrument frame is a rotation ``M_k`` of the sky, so a pixel's
  tangent-plane coordinates in it are the exact projective map ``t = (M_k s)_xy / (M_k s)_z``
  of its unit vector ``s``, and ``q = 1 / (M_k s)_z``.  A roll is exactly a shift of the
  mask angle at which the sky is projected; a tilt is a shift along ``w`` only to first
  order (its error, ``~0.6 (L/R) |t|^2 eps``, exceeds 1e-4 above ~0.5' on a 7 deg
  field), so
  the exact map, six multiply-adds and a division per pixel, is used for both;
* the projections of every (interval, time bin) pair with exposure are summed, weighted,
  into ONE projection per bin before the detector stage, which then runs once per product
  (not once per interval);
* so a product costs one splat of the sky per (interval, bin) pair with exposure --
  intervals that cut a flight more finely cover fewer bins each, so the total is about the
  bins the flight sweeps -- and one detector stage.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import numpy as np
from numba import njit, prange

from rotmod.errors import ParameterError
from rotmod.events.folding import exposure_per_bin
from rotmod.limits import check_memory
from rotmod.response.materialised import MaterialisedResponse, build_response
from rotmod.response.operator import ResponseOperator
from rotmod.response.parallel import block_ranges
from rotmod.response.radon import (
    _FMA,
    BLOCK_BYTES,
    DEFAULT_TOLERANCE,
    RadonResponse,
    _detect,
    _detect_adjoint,
    _like,
    _morton_order,
    _node,
)
from rotmod.response.spec import ResponseSpec, as_spec
from rotmod.sky.attitude import attitude_rotations
from rotmod.sky.points import DirectionList

__all__ = ["DriftResponse", "RadonDriftResponse", "drift_response"]

#: Shares of a bin's exposure treated as none in :class:`RadonDriftResponse` (rounding).
NEGLIGIBLE_SHARE = 1e-12


class DriftResponse(ResponseOperator):
    """``P = sum_k W_k P_k``: operators ``P_k`` weighted bin by bin (``W_k = diag_t(w_k)``).

    Parameters
    ----------
    parts : list of ResponseOperator
        One per attitude interval, all of the same shape.
    weights : ndarray, shape (n_parts, n_time)
        ``exposure_k[t] / sum_k exposure_k[t]`` (0 where a bin has no exposure).
    spec : ResponseSpec, optional
        What the sum is the response of (the image grid); default: the first part's
        metadata, without a grid.

    Notes
    -----
    ``forward(S) = sum_k w_k[t] P_k S`` and ``adjoint(Y) = sum_k P_k^T (w_k[t] Y)``.
    """

    def __init__(self, parts: list[ResponseOperator], weights: np.ndarray,
                 spec: ResponseSpec | None = None) -> None:
        if not parts:
            raise ParameterError("parts must hold at least one response operator")
        first = parts[0]
        self.parts = parts
        self.weights = np.asarray(weights, dtype=np.float64)
        if spec is not None:
            self._adopt(spec)
            return
        self.n_det, self.n_time, self.n_sky = first.n_det, first.n_time, first.n_sky
        self.dtype = first.dtype
        self.instrument, self.time_bins = first.instrument, first.time_bins
        self.model, self.energy = first.model, first.energy
        self.grid = None

    def components(self) -> list[tuple[np.ndarray | None, ResponseSpec]]:
        """One ``(weights, spec)`` per attitude interval (see the base class)."""
        return [(w * pw if pw is not None else w, ps)
                for w, part in zip(self.weights, self.parts, strict=True)
                for pw, ps in part.components()]

    def _forward(self, sky: np.ndarray) -> np.ndarray:
        out = np.zeros((self.n_det, self.n_time))
        for w, part in zip(self.weights, self.parts, strict=True):
            out += w[None, :] * part.forward(sky)
        return out.astype(self.dtype, copy=False)

    def _adjoint(self, counts: np.ndarray) -> np.ndarray:
        out = np.zeros(self.n_sky)
        y = np.asarray(counts, dtype=np.float64)
        for w, part in zip(self.weights, self.parts, strict=True):
            out += part.adjoint(w[None, :] * y)
        return out.astype(self.dtype, copy=False)


# --- one table, one projection per bin: the drift's Radon structure (docs/physics.md 2c) ---


@njit(cache=True, inline="always", fastmath=_FMA)
def _lagrange_at(q, nodes, inv_den, out):
    """Lagrange weights of ``nodes`` at ``q`` into ``out`` (``inv_den[r, m] = 1 / (q_r -
    q_m)``, the diagonal unused)."""
    n_r = nodes.size
    for r in range(n_r):
        c = 1.0
        for m in range(n_r):
            if m != r:
                c *= (q - nodes[m]) * inv_den[r, m]
        out[r] = c


@njit(cache=True, inline="always", fastmath=_FMA)
def _pixel(s, n, m):
    """Tangent-plane coordinates and ``q = 1 / cos(theta)`` of unit vector ``s[n]`` in the
    frame of the rotation ``m`` (its 9 values, row by row): the exact projective map of a
    rotation (docs/physics.md 2c)."""
    s0, s1, s2 = s[n, 0], s[n, 1], s[n, 2]
    q = 1.0 / (m[6] * s0 + m[7] * s1 + m[8] * s2)
    return (m[0] * s0 + m[1] * s1 + m[2] * s2) * q, (m[3] * s0 + m[4] * s1 + m[5] * s2) * q, q


@functools.cache
def _drift_kernels(n_r: int) -> tuple[Any, Any]:
    """The weighted per-pair projection and its transpose for ``n_r`` optical-depth nodes
    (a closure constant, as :func:`rotmod.response.radon._projection_kernels`).

    A pair is an attitude and a distinct bin ``t`` with two weights: its share of the
    exposure of bin ``t`` (half 0) and of bin ``t + n/2`` (half 1; 0 when the bins share
    their pairs or there is no such bin).  Both see the same angles (the half turn maps an
    interval's mask onto itself), so the pixel geometry is computed once for both.
    """

    @njit(parallel=True, cache=True, fastmath=_FMA)
    def splat(s, sky, rot, nodes, inv_den, ptr, att, w1, w2, ang, cos_a, sin_a, k0, inv_dw,
              out):
        """``out[b, h, sub, k, r] += sum_pairs w_h sum_n sky[n] c_r(q_n) B_k(w_n)``: every
        pair of distinct bin ``b``, its pixels seen through its rotation; one bin per
        thread, the pairs and pixels in order (thread-count independent)."""
        n_b, n_sub = out.shape[0], out.shape[2]
        n_pix = s.shape[0]
        for b in prange(n_b):
            cw = np.empty(n_r)
            like = out[b, 0, 0, 0, 0]  # the output's type, for the weights (radon._like)
            for p in range(ptr[b], ptr[b + 1]):
                m = rot[att[p]]
                wa, wb = w1[p], w2[p]
                for n in range(n_pix):
                    tx, ty, q = _pixel(s, n, m)
                    _lagrange_at(q, nodes, inv_den, cw)
                    for sub in range(n_sub):
                        a = ang[b] + sub
                        i, b0, b1, b2, b3 = _node(tx, ty, cos_a[a], sin_a[a], k0, inv_dw, like)
                        for h in range(2):
                            wh = wa if h == 0 else wb
                            if wh == 0.0:
                                continue
                            o = out[b, h, sub]
                            v = sky[n] * wh
                            for r in range(n_r):
                                vr = _like(v * cw[r], like)
                                o[i - 1, r] += b0 * vr
                                o[i, r] += b1 * vr
                                o[i + 1, r] += b2 * vr
                                o[i + 2, r] += b3 * vr

    @njit(parallel=True, cache=True, fastmath=_FMA)
    def gather(s, rot, nodes, inv_den, ptr, att, w1, w2, ang, cos_a, sin_a, k0, inv_dw, gg,
               chunk, acc):
        """``acc[n] += sum_pairs sum_h w_h sum_r c_r(q_n) sum_k B_k(w_n) gg[b, h, sub, k, r]``
        (the transpose of ``splat``): one chunk of pixels per task, bins and pairs in
        order."""
        n_b, n_sub = gg.shape[0], gg.shape[2]
        n_pix = s.shape[0]
        n_chunks = (n_pix + chunk - 1) // chunk
        for ch in prange(n_chunks):
            cw = np.empty(n_r)
            n0 = ch * chunk
            n1 = min(n_pix, n0 + chunk)
            like = gg[0, 0, 0, 0, 0]
            for b in range(n_b):
                for p in range(ptr[b], ptr[b + 1]):
                    m = rot[att[p]]
                    wa, wb = w1[p], w2[p]
                    for n in range(n0, n1):
                        tx, ty, q = _pixel(s, n, m)
                        _lagrange_at(q, nodes, inv_den, cw)
                        for h in range(2):
                            wh = wa if h == 0 else wb
                            if wh == 0.0:
                                continue
                            total = 0.0
                            for sub in range(n_sub):
                                a = ang[b] + sub
                                i, b0, b1, b2, b3 = _node(tx, ty, cos_a[a], sin_a[a], k0,
                                                          inv_dw, like)
                                g = gg[b, h, sub]
                                for r in range(n_r):
                                    total += cw[r] * (b0 * g[i - 1, r] + b1 * g[i, r]
                                                      + b2 * g[i + 1, r] + b3 * g[i + 2, r])
                            acc[n] += wh * total

    return splat, gather


@njit(parallel=True, cache=True)
def _drift_dense(tab, s, rot, nodes, inv_den, ptr, att, w1, w2, ang, cos_a, sin_a, k0, inv_dw,
                 jx, ax, n_sub, out):
    """``out[h, d, b, n]``: every value of the drift response at pixels ``s`` (half ``h`` of
    distinct bin ``b``), with the products' weights, one element at a time (for
    :meth:`RadonDriftResponse.block`); one task per distinct bin."""
    n_det, n_b, n_pix = out.shape[1], out.shape[2], out.shape[3]
    n_r = nodes.size
    for b in prange(n_b):
        cw = np.empty(n_r)
        for p in range(ptr[b], ptr[b + 1]):
            m = rot[att[p]]
            for n in range(n_pix):
                tx, ty, q = _pixel(s, n, m)
                _lagrange_at(q, nodes, inv_den, cw)
                for sub in range(n_sub):
                    a = ang[b] + sub
                    i, b0, b1, b2, b3 = _node(tx, ty, cos_a[a], sin_a[a], k0, inv_dw, 0.0)
                    for d in range(n_det):
                        total = 0.0
                        for tap in range(jx.shape[2]):
                            row = tab[jx[d, a, tap]]
                            dot = 0.0
                            for r in range(n_r):
                                dot += cw[r] * (b0 * row[(i - 1) * n_r + r]
                                                + b1 * row[i * n_r + r]
                                                + b2 * row[(i + 1) * n_r + r]
                                                + b3 * row[(i + 2) * n_r + r])
                            total += ax[d, a, tap] * dot
                        out[0, d, b, n] += w1[p] * total
                        out[1, d, b, n] += w2[p] * total


class RadonDriftResponse(ResponseOperator):
    """The drift response ``sum_k W_k P_k`` of the exact model through ONE Radon table.

    Every attitude interval is a rotation ``M_k`` of the sky (:func:`attitude_rotations`);
    its pixels' tangent-plane coordinates are computed exactly from their unit vectors
    (``t = (M_k s)_xy / (M_k s)_z``, ``q = 1 / (M_k s)_z``) and splatted, weighted by the
    interval's share of each bin's exposure, into one projection per time bin; the detector
    stage of :class:`~rotmod.response.RadonResponse` then runs once per product.  Intervals
    of exactly the same attitude share their pairs.  Build it with
    :func:`drift_response` (``operator="radon"``).

    Parameters
    ----------
    spec : ResponseSpec
        The response on the image grid (a grid with ``sky_coords()``, e.g. a
        :class:`~rotmod.sky.CelestialGrid`), model ``"exact"``.
    attitudes : list of Attitude
        One per interval.
    weights : ndarray, shape (n_intervals, n_time)
        ``exposure_k[t] / sum_k exposure_k[t]`` (0 where a bin has no exposure).
    tolerance : float
        Largest error of any profile value against the exact model, as for
        :class:`~rotmod.response.RadonResponse` (the same table step law).
    block_bins : int, optional
        Time bins per block of projections (default: ~64 MB of them).

    Raises
    ------
    ParameterError
        A pixel at or below the instrument's horizon in some interval, weights of the wrong
        shape, or what :class:`~rotmod.response.RadonResponse` refuses.

    Notes
    -----
    With ``pairs(t)`` the intervals with exposure in bin ``t`` and ``t' = t mod n_distinct``
    (the half turn maps each interval's mask onto itself)::

        forward(S)[d, t] = (1/n_sub) sum_{xi in t'} sum_j A_j(delta_d(xi) mod p)
            sum_{k, r} Psi[j, k, r] sum_{i in pairs(t)} w_i[t] sum_n B_k(w_ni(xi)) c_r(q_ni) S[n]

    and ``adjoint`` is its transpose (the dot test holds to rounding).
    """

    def __init__(self, spec: ResponseSpec, attitudes: list[Any], weights: np.ndarray, *,
                 tolerance: float = DEFAULT_TOLERANCE, block_bins: int | None = None) -> None:
        self._adopt(spec)
        wts = np.asarray(weights, dtype=np.float64)
        if wts.shape != (len(attitudes), self.n_time) or not np.all(np.isfinite(wts)):
            raise ParameterError(f"weights must be finite, of shape ({len(attitudes)}, "
                                 f"{self.n_time}) (intervals x time bins), got {wts.shape}")
        if self.grid.frame != "celestial":
            raise ParameterError("grid: a drift response needs pixels on the sky (a celestial "
                                 f"or HEALPix grid, frame 'celestial'), got {self.grid!r}")
        sky = self.grid.sky_coords().cartesian.xyz.value.T  # (n_sky, 3) ICRS unit vectors
        rot_all = attitude_rotations(attitudes)
        # Intervals of one attitude are one pair per bin (their weights add).
        rot, which = np.unique(rot_all.reshape(-1, 9), axis=0, return_inverse=True)
        rot = np.ascontiguousarray(rot.reshape(-1, 3, 3))  # (attitudes, 3, 3)
        merged = np.zeros((rot.shape[0], self.n_time))
        np.add.at(merged, which.ravel(), wts)
        # Exposure shares of ~1e-16 are the rounding of bin edges (exposure_per_bin), not
        # exposure: they would cost a splat each (~4 % more pairs for 10 s intervals) for a
        # change of the response far below rounding.
        merged[np.abs(merged) <= NEGLIGIBLE_SHARE] = 0.0
        # Each attitude's pixels: their zenith range (all of them set the one table) and the
        # bounding box of their tangent-plane coordinates (the w range each angle uses).
        cos_z = np.empty((rot.shape[0], 2))
        box = np.empty((rot.shape[0], 4))  # tx min, tx max, ty min, ty max
        step = max(1, (1 << 22) // max(1, sky.shape[0]))
        for a0 in range(0, rot.shape[0], step):
            u = np.einsum("nc,kic->kin", sky, rot[a0:a0 + step])  # (k, 3, n_sky)
            cos_z[a0:a0 + step] = np.stack([u[:, 2].min(1), u[:, 2].max(1)], axis=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                tx, ty = u[:, 0] / u[:, 2], u[:, 1] / u[:, 2]
            box[a0:a0 + step] = np.stack([tx.min(1), tx.max(1), ty.min(1), ty.max(1)], axis=1)
        cos_lo, cos_hi = float(cos_z[:, 0].min()), float(cos_z[:, 1].max())
        if cos_lo <= 0.0:
            raise ParameterError(
                "intervals: every pixel must be above the detector plane (theta < 90 deg) in "
                f"every attitude interval, got theta {np.degrees(np.arccos(cos_lo)):.3g} deg")
        extremes = DirectionList(np.degrees(np.arccos([cos_hi, cos_lo])), [0.0, 0.0])
        base = RadonResponse(spec.replace(grid=extremes), tolerance=tolerance,
                             block_bins=block_bins)
        self.tolerance = base.tolerance
        f = base._factors
        nodes = np.asarray(f.q_nodes, dtype=np.float64)
        with np.errstate(divide="ignore"):
            self._inv_den = 1.0 / (nodes[:, None] - nodes[None, :])
        self._nodes = nodes
        u0 = sky @ rot[0].T
        self._perm = _morton_order(u0[:, 0] / u0[:, 2], u0[:, 1] / u0[:, 2])
        self._sky = np.ascontiguousarray(sky[self._perm])
        self._rot = np.ascontiguousarray(rot.reshape(-1, 9))  # row by row, for the kernels
        # The (attitude, distinct bin) pairs with exposure in bin t (weight w1) or t + n/2
        # (w2): both see the same angles (the half turn maps each interval's mask onto
        # itself).  Where every pair of a bin has w1 == w2 (intervals of whole turns), the
        # two bins are equal: half 1 is not computed but copied.
        nd = base.n_distinct
        w1 = merged[:, :nd]
        w2 = np.zeros_like(w1)
        w2[:, : self.n_time - nd] = merged[:, nd:]
        self._same = np.all(w1 == w2, axis=0) & (self.n_time > nd)  # (nd,)
        w2[:, self._same] = 0.0
        p_bin, p_att = np.nonzero((w1 != 0.0).T | (w2 != 0.0).T)
        self._ptr = np.searchsorted(p_bin, np.arange(nd + 1)).astype(np.int64)
        self._att = p_att.astype(np.int64)
        self._w1 = np.ascontiguousarray(w1[p_att, p_bin])
        self._w2 = np.ascontiguousarray(w2[p_att, p_bin])
        self._half = self.n_time > nd  # whether there is a second half turn of bins
        # The used w range of every angle: the corners of the boxes of its pairs' pixels.
        n_sub = f.n_sub
        self._ang = np.arange(nd, dtype=np.int64) * n_sub
        out_ang = (p_bin[:, None] * n_sub + np.arange(n_sub)).ravel()  # (pairs * n_sub,)
        bx = box[np.repeat(self._att, n_sub)]
        c_a, s_a = f.cos_a[out_ang], f.sin_a[out_ang]
        w_c = np.stack([bx[:, i] * c_a - bx[:, j] * s_a for i in (0, 1) for j in (2, 3)])
        w_lo = np.full(f.cos_a.size, np.inf)
        w_hi = np.full(f.cos_a.size, -np.inf)
        np.minimum.at(w_lo, out_ang, w_c.min(0))
        np.maximum.at(w_hi, out_ang, w_c.max(0))
        used = np.isfinite(w_lo)
        k_lo = np.zeros(f.cos_a.size, dtype=np.int64)
        k_hi = np.zeros(f.cos_a.size, dtype=np.int64)  # an angle without exposure: no work
        k_lo[used] = (np.floor(f.k0 + w_lo[used] * f.inv_dw).astype(np.int64) - 2) * f.n_q
        k_hi[used] = (np.floor(f.k0 + w_hi[used] * f.inv_dw).astype(np.int64) + 4) * f.n_q
        size = f.n_w * f.n_q
        self._factors = dataclasses.replace(f, k_lo=np.clip(k_lo, 0, size),
                                            k_hi=np.clip(k_hi, 0, size))
        per_bin = 2 * n_sub * size * self.dtype.itemsize
        nb = block_bins or max(1, min(nd, BLOCK_BYTES // max(1, per_bin)))
        self.blocks = [(t0, min(nd, t0 + nb)) for t0 in range(0, nd, nb)]
        self.weights = wts
        self.sum_of = [(w, spec.replace(grid=dataclasses.replace(self.grid, attitude=att)))
                       for w, att in zip(wts, attitudes, strict=True)]

    @property
    def n_pairs(self) -> int:
        """(Attitude, distinct bin) pairs with exposure: the projections a product splats
        (each for one or both of the bins ``t``, ``t + n/2``)."""
        return int(self._att.size)

    @property
    def table(self) -> np.ndarray:
        """The one table ``Psi`` shared by every interval (as ``RadonResponse.table``)."""
        return self._factors.table

    def _halves(self, t0: int, t1: int) -> tuple[np.ndarray, np.ndarray]:
        """Bins ``t0:t1`` whose half 1 is computed (the others copy half 0), and the
        factors' angles of their sub-angles."""
        bins = np.arange(t0, t1)[~self._same[t0:t1]] if self._half else np.arange(0)
        n_sub = self._factors.n_sub
        return bins, (bins[:, None] * n_sub + np.arange(n_sub)).ravel()

    def _forward(self, sky: np.ndarray) -> np.ndarray:
        f = self._factors
        nd, n_sub = self._ang.size, f.n_sub
        x = np.asarray(sky, dtype=np.float64)[self._perm]
        splat, _ = _drift_kernels(f.n_q)
        out = np.empty((self.n_det, nd + (nd if self._half else 0)))
        for t0, t1 in self.blocks:
            rr = np.zeros((t1 - t0, 2, n_sub, f.n_w, f.n_q), dtype=self.dtype)
            splat(self._sky, x, self._rot, self._nodes, self._inv_den, self._ptr[t0:t1 + 1],
                  self._att, self._w1, self._w2, self._ang[t0:t1], f.cos_a, f.sin_a, f.k0,
                  f.inv_dw, rr)
            sl = slice(t0 * n_sub, t1 * n_sub)
            rates = _detect(f, sl, rr[:, 0].reshape(-1, f.n_w * f.n_q))
            out[:, t0:t1] = rates.reshape(self.n_det, t1 - t0, n_sub).sum(2, dtype=np.float64)
            if self._half:
                out[:, nd + t0:nd + t1] = out[:, t0:t1]  # the bins that share their pairs
                bins, angles = self._halves(t0, t1)
                if bins.size:
                    flat = rr[bins - t0, 1].reshape(-1, f.n_w * f.n_q)
                    rates = _detect(f, angles, flat)
                    out[:, nd + bins] = rates.reshape(self.n_det, bins.size, n_sub).sum(
                        2, dtype=np.float64)
        return out[:, : self.n_time].astype(self.dtype, copy=False)

    def _adjoint(self, counts: np.ndarray) -> np.ndarray:
        f = self._factors
        nd, n_sub = self._ang.size, f.n_sub
        y = np.asarray(counts, dtype=np.float64)
        y0 = y[:, :nd].copy()
        if self._half:
            y0[:, self._same] += y[:, nd:][:, self._same]  # the transpose of the copy
        _, gather = _drift_kernels(f.n_q)
        acc = np.zeros(self.n_sky)
        chunk = max(256, -(-self.n_sky // 64))  # as RadonResponse: 64 chunks of pixels
        for t0, t1 in self.blocks:
            gg = np.zeros((t1 - t0, 2, n_sub, f.n_w * f.n_q), dtype=self.dtype)
            ya = np.repeat(np.ascontiguousarray(y0[:, t0:t1], dtype=self.dtype), n_sub, axis=1)
            gg[:, 0] = _detect_adjoint(f, slice(t0 * n_sub, t1 * n_sub), ya).reshape(
                t1 - t0, n_sub, -1)
            bins, angles = self._halves(t0, t1)
            if bins.size:
                ya = np.repeat(np.ascontiguousarray(y[:, nd + bins], dtype=self.dtype), n_sub,
                               axis=1)
                gg[bins - t0, 1] = _detect_adjoint(f, angles, ya).reshape(bins.size, n_sub, -1)
            gather(self._sky, self._rot, self._nodes, self._inv_den, self._ptr[t0:t1 + 1],
                   self._att, self._w1, self._w2, self._ang[t0:t1], f.cos_a, f.sin_a, f.k0,
                   f.inv_dw, gg.reshape(t1 - t0, 2, n_sub, f.n_w, f.n_q), chunk, acc)
        out = np.empty(self.n_sky)
        out[self._perm] = acc
        return out.astype(self.dtype, copy=False)

    def block(
        self, t: tuple[int, int] | None = None, n: tuple[int, int] | None = None
    ) -> np.ndarray:
        """``P[:, t0:t1, n0:n1]`` (``None`` = whole axis): the values the products use,
        evaluated pixel by pixel from the table (so :meth:`materialise`, ``columns_at`` of
        the grid's pixels and the default ``adjoint_squared`` need no product per pixel)."""
        (t0, t1), (n0, n1) = block_ranges(t, n, self.n_time, self.n_sky)
        f = self._factors
        nd = self._ang.size
        check_memory(2.0 * self.n_det * nd * (n1 - n0) * 8.0,
                     f"a drift response of {self.n_det} x {self.n_time} x {n1 - n0} values",
                     hint="ask for fewer pixels at a time")
        where = np.empty(self.n_sky, dtype=np.int64)
        where[self._perm] = np.arange(self.n_sky)  # each pixel's place in the kernels' order
        part = np.zeros((2, self.n_det, nd, n1 - n0))
        _drift_dense(f.table, np.ascontiguousarray(self._sky[where[n0:n1]]), self._rot,
                     self._nodes, self._inv_den, self._ptr, self._att, self._w1, self._w2,
                     self._ang, f.cos_a, f.sin_a, f.k0, f.inv_dw, f.jx, f.ax, f.n_sub, part)
        out = part[0]
        if self._half:
            second = np.where(self._same[None, :, None], part[0], part[1])
            out = np.concatenate([part[0], second], axis=1)[:, : self.n_time]
        return out[:, t0:t1].astype(self.dtype, copy=False)

    def metadata(self) -> dict[str, Any]:
        """As :meth:`ResponseOperator.metadata`, plus ``operator``: ``kind`` "radon-drift",
        ``tolerance``, the table's shape and the number of (attitude, bin) pairs."""
        meta = super().metadata()
        f = self._factors
        meta["operator"] = {"kind": "radon-drift", "tolerance": self.tolerance,
                            "table": [int(f.table.shape[0]), f.n_w, f.n_q],
                            "pairs": self.n_pairs}
        return meta

    def __repr__(self) -> str:
        f = self._factors
        return (super().__repr__()[:-1] + f", tolerance {self.tolerance:g}, table "
                f"{f.table.shape[0]} x {f.n_w} x {f.n_q}, {len(self.sum_of)} intervals, "
                f"{self.n_pairs} pairs>")


def drift_response(
    instrument: Any,
    grid: Any = None,
    time_bins: Any = None,
    intervals: list[tuple[float, float, Any]] | None = None,
    model: Any = None,
    energy: Any = None,
    *,
    start_phase: Any = 0.0,
    dtype: Any = None,
    operator: str = "matrix",
    tolerance: float | None = None,
) -> ResponseOperator:
    """Exposure-weighted response over attitude ``intervals`` (see the module notes).

    Parameters
    ----------
    instrument : Instrument or ResponseSpec
        The instrument, or a whole :class:`~rotmod.response.ResponseSpec` (on the image
        grid; then give ``intervals`` by name and no other field).
    grid : CelestialGrid
        The image grid; its attitude is replaced by each interval's.
    time_bins : int or TimeBinning
    intervals : list of (t_lo, t_hi, Attitude)
        E.g. :meth:`rotmod.sky.AttitudeTable.intervals`; times in s.
    model, energy, dtype
        As for :func:`~rotmod.response.build_response` (``dtype`` default float64).
    start_phase : float or Quantity
        Mask angle at ``t = 0`` (deg if plain), as in the event list.
    operator : {"matrix", "radon", "radon-per-interval"}
        Hold the summed matrix; or a :class:`RadonDriftResponse` (the exact model within
        ``tolerance`` through one table, products almost independent of the number of
        intervals; ``model`` must be ``"exact"``); or, for comparisons, the straightforward
        :class:`DriftResponse` of one :class:`~rotmod.response.RadonResponse` per interval
        (a table and a product per interval).
    tolerance : float, optional
        With the Radon operators only: the largest error of any profile value (default
        1e-4).  Refused with ``operator="matrix"``, which holds the model's values without
        interpolation (a tolerance there would be silently ignored).

    Returns
    -------
    MaterialisedResponse, RadonDriftResponse or DriftResponse

    Raises
    ------
    ParameterError
        An unknown operator, no intervals, a model the Radon operators cannot factorise, or a
        ``tolerance`` with ``operator="matrix"``.
    """
    spec = as_spec(instrument, grid, time_bins, model, energy, dtype=dtype,
                   default_dtype=np.float64)
    tb, grid, inst = spec.time_bins, spec.grid, spec.instrument
    if operator not in ("matrix", "radon", "radon-per-interval"):
        raise ParameterError("operator must be 'matrix', 'radon' or 'radon-per-interval', got "
                             f"{operator!r}")
    if not intervals:
        raise ParameterError("intervals must hold at least one attitude interval")
    if operator == "matrix" and tolerance is not None:
        raise ParameterError(
            f"tolerance: only the Radon operators interpolate (operator 'radon' or "
            f"'radon-per-interval'); operator 'matrix' holds the model's values exactly, "
            f"so tolerance = {tolerance!r} would be ignored")
    tolerance = DEFAULT_TOLERANCE if tolerance is None else tolerance
    weights = np.array([exposure_per_bin([[lo, hi]], tb.n_bins, inst.rotation_period,
                                         start_phase) for lo, hi, _ in intervals])
    total = weights.sum(axis=0)

    def at(att: Any, **changes: Any) -> ResponseSpec:
        """The spec of one interval: the grid at its attitude."""
        return spec.replace(grid=dataclasses.replace(grid, attitude=att), **changes)

    if operator != "matrix":
        if spec.model.name != "exact":
            raise ParameterError(f"model: operator {operator!r} factorises the exact model, "
                                 f"got {spec.model.name!r}")
        with np.errstate(invalid="ignore", divide="ignore"):
            norm = np.where(total > 0, weights / total, 0.0)
        if operator == "radon":
            return RadonDriftResponse(spec, [att for _, _, att in intervals], norm,
                                      tolerance=tolerance)
        parts: list[ResponseOperator] = [RadonResponse(at(att), tolerance=tolerance)
                                         for _, _, att in intervals]
        return DriftResponse(parts, norm, spec)
    n_det = len(inst.detectors)
    check_memory(2 * 8.0 * n_det * tb.n_bins * grid.size,
                 f"a drift response of {n_det} x {tb.n_bins} x {grid.size}",
                 hint="use fewer pixels or time bins")
    acc = np.zeros((n_det, tb.n_bins, grid.size))
    for w, (_, _, att) in zip(weights, intervals, strict=True):
        part = build_response(at(att, dtype=np.float64))
        acc += w[None, :, None] * part.matrix
    with np.errstate(invalid="ignore", divide="ignore"):
        matrix = np.where(total[None, :, None] > 0, acc / total[None, :, None], 0.0)
        norm = np.where(total > 0, weights / total, 0.0)
    # The matrix remembers its intervals: a source between pixels is evaluated at each
    # interval's attitude, as the matrix was (columns_at).
    return MaterialisedResponse(matrix.astype(spec.dtype), spec=spec,
                                sum_of=[(w, at(att)) for w, (_, _, att)
                                        in zip(norm, intervals, strict=True)])
