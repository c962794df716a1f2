"""The Radon-factorised response: wide fields at the cost of a projection, not of ``P``.

For detector ``d`` at mask angle ``xi`` and a sky pixel with tangent-plane coordinates
``t = tan(theta) (cos phi, sin phi)`` (derivation in ``docs/physics.md``, "The Radon
structure of the response"):

* the mask coordinate of the ray to the detector centre is ``uc = delta_d(xi) + L w``, with
  ``delta_d = x_d cos xi - y_d sin xi`` and ``w = t_x cos xi - t_y sin xi`` (the pixel's sky
  coordinate across the slats);
* the ray's growth across the slab is ``s = h w`` and the slat optical depth is
  ``tau = mu h q`` with ``q = 1 / cos(theta) = sqrt(1 + |t|^2)``.

So ``P[d, xi, n] = E(delta_d + L w_n, h w_n, mu h q_n)`` with ``E`` the exact profile of one
detector (:mod:`rotmod.profiles.exact`), periodic in its first argument with the mask period
``p = a + b``.  One table ``Psi[j, k, r] = E(x_j + L w_k, h w_k, mu h q_r)`` on a grid of
detector offsets ``x_j`` in ``[0, p)``, sky coordinates ``w_k`` and ``q`` nodes ``q_r`` serves
every detector, angle and pixel:

* forward, per angle: *splat* the sky onto the ``w`` grid (a Radon projection, shared by all
  detectors; each pixel's weight spread over its ``q`` nodes), then one dot product per
  detector with the table row at ``delta_d mod p``;
* adjoint: the transpose, in the same order (the weights are identical, so the dot test holds
  to rounding).

Interpolation: cubic Lagrange in ``w`` (the splat), linear in ``x`` (periodic) at half the
step, Chebyshev nodes in ``q``.  A profile is ``C^1`` but not ``C^2`` where a shadow edge
crosses the disc's rim (the disc's chord density has a square-root edge), so the
interpolation error there falls as ``step^1.5``: the table step in ``u`` is chosen from
``tolerance`` by the law measured in ``benchmarks/bench_radon.py`` (``docs/response.md``),
and the number of ``q`` nodes by the Chebyshev error bound of ``exp(-tau f)``,
``0 <= f <= 1``.  The table itself is interpolated, cubic in ``s = h w`` between the kinks of
``E`` in ``s``, from ``E`` on the offset nodes and far fewer nodes in ``s`` (the grid of ``w``
is tied to the offset grid so that every ``x_j + L w_k`` is an offset node;
``docs/physics.md`` §2b).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit, prange
from numba.extending import overload

from rotmod._validate import as_int, as_scalar
from rotmod.errors import ModelValidityError, ParameterError, RotmodError
from rotmod.io import response_store as fmt
from rotmod.limits import RATES, check_memory, check_time, measure_rate
from rotmod.profiles.base import CAST_BYTES, ProjectedGeometry
from rotmod.response._plan import distinct_bins, fold_half_turn, repeat_half_turn
from rotmod.response.materialised import MaterialisedResponse
from rotmod.response.operator import ResponseOperator
from rotmod.response.parallel import block_ranges, map_blocks
from rotmod.response.spec import ResponseSpec, as_spec, restore_fields
from rotmod.response.stored import STORE_KINDS, StoreKind

__all__ = ["RadonResponse"]

#: Interpolation error of the table: ``max abs(dP) ~ ERROR_LAW step^1.5``, ``step`` the table
#: spacing in ``u`` in detector radii (cubic in ``w``; in ``x`` cubic, or linear at half the
#: step).
#: Chosen so that the measured error stays below the tolerance with a margin: at most 0.81
#: of it on the paper's whole grid and random geometries (docs/response.md).
ERROR_LAW = 0.15
#: The default ``tolerance`` of the Radon operators (largest error of a profile value).
DEFAULT_TOLERANCE = 1e-4
#: Share of the tolerance given to the ``q`` (optical depth) interpolation.
RING_SHARE = 0.1
#: Share of the tolerance given to the interpolation of ``E`` in the shadow's shift ``s``
#: (the table is built from ``E`` on nodes in ``s``, far coarser than ``h Δw`` when
#: ``h << L``: :func:`_shift_nodes`; the step follows from ``ERROR_LAW``, which
#: over-estimates this error 2x or more: ``benchmarks/bench_radon_shift.py``).
SHIFT_SHARE = 0.05
#: Version of the table's grids, in a stored response's metadata (2: ``L Δw`` a multiple of
#: the offset step, so the table is built from ``E`` on a grid of ``s``).
TABLE_LAYOUT = 2
#: Most ``q`` nodes (the Chebyshev bound needs more only for absurd fields).
MAX_RINGS = 10
#: Detector stage: with ``J`` the rows of a table cubic in the detector offset, use one BLAS
#: product of every row with every projection when ``J <= GEMM_ROWS * n_det`` (and keep the
#: cubic table: its cost is ``J``, its taps are free), else two dot products per detector
#: and angle on a table linear in the offset at half the step (as accurate; two rows read
#: instead of four).  Break-even measured between J / n_det = 9 (BLAS 4x faster, the wide
#: field) and 30 (rows 2x faster, the paper's grid) on this machine (docs/response.md).
GEMM_ROWS = 16
#: Target bytes of one block of splatted angles.
BLOCK_BYTES = 64 << 20


# --- kernels ------------------------------------------------------------------------------


#: Fused multiply-adds only: ~1.5x the speed of the scatter loops, and the same sums
#: whatever the thread count (no reassociation).
_FMA = {"contract"}


@njit(cache=True, inline="always", fastmath=_FMA)
def _cubic(f: Any) -> tuple[Any, Any, Any, Any]:
    """Lagrange weights of the nodes -1, 0, 1, 2 at ``f`` in [0, 1) (a float or an array)."""
    fm1 = f - 1.0
    fm2 = f - 2.0
    fp1 = f + 1.0
    sixth = 1.0 / 6.0  # a multiplication: a division here would dominate the splat
    return (-f * fm1 * fm2 * sixth, fp1 * fm1 * fm2 * 0.5, -fp1 * f * fm2 * 0.5,
            fp1 * f * fm1 * sixth)


def _like(x: float, like: Any) -> Any:
    """``x`` in the type of ``like`` (inside kernels: float32 weights for float32 arrays, so
    the scatter loops do no conversions)."""
    return x


@overload(_like, inline="always")
def _like_impl(x, like):  # numba compares these names (unannotated) with impl's
    target = like

    def impl(x, like):
        return target(x)

    return impl


@njit(cache=True, inline="always", fastmath=_FMA)
def _node(txn, tyn, c, s, k0, inv_dw, like):
    """A pixel's first ``w`` node ``i`` at one angle and the cubic weights of nodes ``i - 1``
    to ``i + 2``, in the type of ``like``."""
    x = k0 + (txn * c - tyn * s) * inv_dw
    i = int(x)
    b0, b1, b2, b3 = _cubic(x - i)
    return i, _like(b0, like), _like(b1, like), _like(b2, like), _like(b3, like)


@functools.cache
def _projection_kernels(n_r: int) -> tuple[Any, Any]:
    """The projection and its transpose compiled for ``n_r`` optical-depth nodes.

    ``n_r`` is a closure constant, so the loops over it have a fixed trip count and vectorise
    (1.5-1.9x faster from 4 nodes up, measured on the wide field); numba's cache keys on it.
    (``numba.literally`` would give the same code but re-types every call: ~20 ms each.)
    """

    @njit(parallel=True, cache=True, fastmath=_FMA)
    def splat(tx, ty, v, cos_a, sin_a, k0, inv_dw, out):
        """``out[a, k, r] += sum_n v[n, r] B_k(w_n(a))`` (cubic weights ``B``), one angle
        per thread, so each ``out[a]`` is summed in pixel order whatever the thread count."""
        n_ang = cos_a.size
        n_pix = tx.size
        for a in prange(n_ang):
            c = cos_a[a]
            s = sin_a[a]
            o = out[a]
            for n in range(n_pix):
                i, b0, b1, b2, b3 = _node(tx[n], ty[n], c, s, k0, inv_dw, o[0, 0])
                for r in range(n_r):
                    vr = v[n, r]
                    o[i - 1, r] += b0 * vr
                    o[i, r] += b1 * vr
                    o[i + 1, r] += b2 * vr
                    o[i + 2, r] += b3 * vr

    @njit(parallel=True, cache=True, fastmath=_FMA)
    def gather(tx, ty, cos_a, sin_a, k0, inv_dw, gg, chunk, acc):
        """``acc[n, r] += sum_a sum_k B_k(w_n(a)) gg[a, k, r]`` (the transpose of ``splat``),
        one chunk of pixels per task and the angles in order, so the sums do not depend on
        the thread count."""
        n_pix = tx.size
        n_ang = cos_a.size
        n_chunks = (n_pix + chunk - 1) // chunk
        for ch in prange(n_chunks):
            n0 = ch * chunk
            n1 = min(n_pix, n0 + chunk)
            for a in range(n_ang):
                c = cos_a[a]
                s = sin_a[a]
                g = gg[a]
                for n in range(n0, n1):
                    i, b0, b1, b2, b3 = _node(tx[n], ty[n], c, s, k0, inv_dw, g[0, 0])
                    for r in range(n_r):
                        acc[n, r] += (b0 * g[i - 1, r] + b1 * g[i, r] + b2 * g[i + 1, r]
                                      + b3 * g[i + 2, r])

    return splat, gather


#: Partial sums per dot product: explicit lanes vectorise where a single accumulator does
#: not (2.6x faster measured), in a fixed order whatever the thread count.
_LANES = 16


@njit(parallel=True, cache=True, fastmath=_FMA)
def _rows_forward(tab, rr, jx, ax, lo, hi, out):
    """``out[d, a] = sum_tap ax[d, a, tap] (tab[jx[d, a, tap]] . rr[a])`` (two taps: linear in
    the detector offset) over the used range ``[lo[a], hi[a])`` of each splat row, in the
    arrays' type."""
    n_det, n_ang = out.shape
    for idx in prange(n_det * n_ang):
        d = idx // n_ang
        a = idx % n_ang
        r0 = tab[jx[d, a, 0]]
        r1 = tab[jx[d, a, 1]]
        a0 = ax[d, a, 0]
        a1 = ax[d, a, 1]
        x = rr[a]
        lanes = np.zeros(_LANES, dtype=rr.dtype)
        k = lo[a]
        while k + _LANES <= hi[a]:
            for m in range(_LANES):
                lanes[m] += (a0 * r0[k + m] + a1 * r1[k + m]) * x[k + m]
            k += _LANES
        acc = lanes.sum()
        for kk in range(k, hi[a]):
            acc += (a0 * r0[kk] + a1 * r1[kk]) * x[kk]
        out[d, a] = acc


@njit(parallel=True, cache=True, fastmath={"contract", "reassoc"})
def _rows_adjoint(tab, y, jx, ax, lo, hi, gg):
    """``gg[a] = sum_d y[d, a] sum_tap ax[d, a, tap] tab[jx[d, a, tap]]`` (the transpose of
    :func:`_rows_forward`)."""
    n_det, n_ang = y.shape
    for a in prange(n_ang):
        g = gg[a]
        for d in range(n_det):
            yd = y[d, a]
            if yd == 0.0:
                continue
            c0 = yd * ax[d, a, 0]
            c1 = yd * ax[d, a, 1]
            r0 = tab[jx[d, a, 0]]
            r1 = tab[jx[d, a, 1]]
            for k in range(lo[a], hi[a]):
                g[k] += c0 * r0[k] + c1 * r1[k]


@njit(parallel=True, cache=True)
def _dense(tab, tx, ty, qw, cos_a, sin_a, k0, inv_dw, jx, ax, n_sub, out):
    """``out[d, t, n]``: every value of the factorised response (the same weights as the
    products, evaluated one element at a time; for columns, checks and small problems).

    One task per time bin; a pixel's ``w`` node and its cubic x optical-depth weights are
    computed once per angle and serve every detector (a dot product of ``4 n_r`` table
    values per detector and tap)."""
    n_det, n_t, n_pix = out.shape
    n_r = qw.shape[1]
    n_taps = jx.shape[2]
    for t in prange(n_t):
        acc = np.zeros((n_det, n_pix))
        wts = np.empty(4 * n_r)
        for sub in range(n_sub):
            a = t * n_sub + sub
            c = cos_a[a]
            s = sin_a[a]
            for n in range(n_pix):
                i, b0, b1, b2, b3 = _node(tx[n], ty[n], c, s, k0, inv_dw, 0.0)
                for r in range(n_r):
                    q = qw[n, r]
                    wts[r] = b0 * q
                    wts[n_r + r] = b1 * q
                    wts[2 * n_r + r] = b2 * q
                    wts[3 * n_r + r] = b3 * q
                base = (i - 1) * n_r
                for d in range(n_det):
                    total = 0.0
                    for tap in range(n_taps):
                        row = tab[jx[d, a, tap]]
                        dot = 0.0
                        for m in range(4 * n_r):
                            dot += wts[m] * row[base + m]
                        total += ax[d, a, tap] * dot
                    acc[d, n] += total
        for d in range(n_det):
            for n in range(n_pix):
                out[d, t, n] = acc[d, n]


@njit(parallel=True, cache=True, fastmath=_FMA)
def _table_rows(coarse, j0, ratio, k0, node0, wts, out):
    """``out[j - j0, k, r]``: table rows ``j0 ...`` from ``coarse[m, i, r] = E(x_i, s_m,
    tau_r)``: ``sum_t wts[|k - k0|, t] coarse[node0[|k - k0|] + t, i, r]``.

    ``x_j + L w_k = x_i`` exactly, ``i = j + ratio (k - k0) mod J``; for ``w_k < 0`` the mirror
    ``E(u, s) = E(-u, -s)`` gives ``i = -(j + ratio (k - k0)) mod J`` at ``|s|``.  Clipped to
    [0, 1], where every profile value lies (so clipping only removes error)."""
    n_rows, n_w, n_r = out.shape
    n_x = coarse.shape[1]
    n_taps = wts.shape[1]
    for jj in prange(n_rows):
        j = j0 + jj
        for k in range(n_w):
            dk = k - k0
            i = (j + ratio * dk) % n_x if dk >= 0 else (-(j + ratio * dk)) % n_x
            a = abs(dk)
            m = node0[a]
            for r in range(n_r):
                acc = 0.0
                for t in range(n_taps):
                    acc += wts[a, t] * coarse[m + t, i, r]
                # A profile value lies in [0, 1]; the cubic may overshoot by its error.
                out[jj, k, r] = min(max(acc, 0.0), 1.0)


# --- setup ----------------------------------------------------------------------------------


def _ring_count(tau_lo: float, tau_hi: float, tol: float) -> int:
    """Fewest Chebyshev nodes in ``tau`` that interpolate ``P(tau)`` within ``tol``.

    ``P(tau) = ∫ exp(-tau f(u)) dΦ(u)`` with path fractions ``0 <= f <= 1``, so
    ``|P^(n)| <= max_{0<=f<=1} f^n exp(-tau_lo f)``, and ``n`` Chebyshev nodes on an interval
    of half-width ``h`` interpolate within ``|P^(n)| h^n / (2^(n-1) n!)``.
    """
    if not math.isfinite(tau_hi) or tau_hi - tau_lo <= 0.0:
        return 1
    half = 0.5 * (tau_hi - tau_lo)
    for n in range(1, MAX_RINGS + 1):
        deriv = (n / tau_lo) ** n * math.exp(-n) if n < tau_lo else math.exp(-tau_lo)
        if deriv * half**n / (2 ** (n - 1) * math.factorial(n)) <= tol:
            return n
    return MAX_RINGS


def _shift_nodes(s: np.ndarray, scale: float, a: float, b: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nodes in the shadow's shift from which ``E`` is interpolated at shifts ``s >= 0``.

    Returns the nodes, and per shift the first of its nodes and their weights ``(len(s),
    taps)``.  At fixed offset, ``E`` is ``C^1`` in ``s`` (the ``step^1.5`` law of ``u``, with
    a smaller constant, measured in docs/response.md) but for kinks at the same ``s`` for
    every offset, where a piece of the shadow pattern vanishes: ``s = 0`` (``|s|``), and
    ``n p + a``, ``n p + b``, ``(n + 1) p`` (a slat's full-thickness core, a gap's clear view,
    ...).  So the nodes are uniform between kinks, at a step set by ``SHIFT_SHARE`` of the
    tolerance (``scale`` = tolerance x radius^1.5), at least four per segment, and each
    shift's four (cubic) nodes lie in its own segment.  Where that needs as many nodes as
    there are shifts (masks thick for their height), the shifts themselves are the nodes
    (one tap of weight 1: the values exact).
    """
    ds = (SHIFT_SHARE * scale / ERROR_LAW) ** (2.0 / 3.0)
    s_max = float(s.max())
    p = a + b
    kinks = {0.0}
    for n in range(int(s_max // p) + 1):
        kinks |= {n * p + a, n * p + b, (n + 1) * p}
    edges = [0.0]
    for v in sorted(kinks):
        if 1e-12 * p < v - edges[-1] and v < s_max:
            edges.append(v)
    edges.append(max(s_max, edges[-1]))
    lo, hi = np.array(edges[:-1]), np.array(edges[1:])
    n_seg = np.maximum(4, np.ceil((hi - lo) / ds).astype(np.int64) + 1)
    if int(n_seg.sum()) >= s.size:
        return s.copy(), np.arange(s.size), np.ones((s.size, 1))
    step = np.where(hi > lo, (hi - lo) / (n_seg - 1), ds)
    start = np.concatenate([[0], np.cumsum(n_seg)[:-1]])
    nodes = np.concatenate([lo[g] + step[g] * np.arange(n_seg[g]) for g in range(lo.size)])
    seg = np.clip(np.searchsorted(hi, s, side="right"), 0, lo.size - 1)
    pos = (s - lo[seg]) / step[seg]
    m = np.clip(np.floor(pos).astype(np.int64), 1, n_seg[seg] - 3)
    return nodes, start[seg] + m - 1, np.stack(_cubic(pos - m), axis=-1)


def _one_detector_values(model: Any, instrument: Any, u: np.ndarray, s: np.ndarray,
                         tau: float, mu: float) -> np.ndarray:
    """``E(u_i, s_m, tau)`` of ``model`` for offsets ``u`` (rows) and shadow shifts ``s``
    (columns): the one-detector profile the table holds (``docs/physics.md`` §2b)."""
    uc = np.repeat(u[:, None], s.size, axis=1)
    zeros_s = np.zeros(s.size)
    geom = ProjectedGeometry(uc, np.zeros_like(uc), s, zeros_s, np.full(s.size, tau),
                             zeros_s, zeros_s, mu)
    out = np.empty((u.size, 1, s.size))
    model.evaluate(instrument, geom, np.ones(1), np.zeros(1), out)
    return out[:, 0, :]


def _lagrange(x: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """Lagrange basis weights ``(x.size, nodes.size)`` of ``nodes`` at ``x``."""
    w = np.ones((x.size, nodes.size))
    for m in range(nodes.size):
        for k in range(nodes.size):
            if k != m:
                w[:, m] *= (x - nodes[k]) / (nodes[m] - nodes[k])
    return w


def _morton_order(tx: np.ndarray, ty: np.ndarray) -> np.ndarray:
    """A permutation putting pixels in Z order, so that a run of consecutive pixels is a
    compact patch of sky and the adjoint's reads of the table stay in cache."""
    def quant(v: np.ndarray) -> np.ndarray:
        lo, hi = float(v.min()), float(v.max())
        scale = 65535.0 / (hi - lo) if hi > lo else 0.0
        return ((v - lo) * scale).astype(np.uint64)

    key = np.zeros(tx.size, dtype=np.uint64)
    qx, qy = quant(tx), quant(ty)
    for bit in range(16):
        key |= ((qx >> np.uint64(bit)) & np.uint64(1)) << np.uint64(2 * bit)
        key |= ((qy >> np.uint64(bit)) & np.uint64(1)) << np.uint64(2 * bit + 1)
    return np.argsort(key, kind="stable")


@dataclass(frozen=True)
class _Factors:
    """Everything a block of angles needs (picklable: the unit of work on a Dask cluster)."""

    table: np.ndarray  # (J, K * R): Psi[j, k, r] flattened over (k, r)
    n_w: int  # K
    n_q: int  # R
    k0: float  # index of w = 0
    inv_dw: float
    tx: np.ndarray  # (N,) float64, pixels in Z order
    ty: np.ndarray
    q_weights: np.ndarray  # (N, R)
    cos_a: np.ndarray  # (n_angles,) every sub-sample of every distinct bin
    sin_a: np.ndarray
    jx: np.ndarray  # (D, n_angles, taps) table rows of each detector and angle
    ax: np.ndarray  # (D, n_angles, taps) their weights (cubic: 4 taps, linear: 2), / n_sub
    k_lo: np.ndarray  # (n_angles,) used range of the flattened splat row
    k_hi: np.ndarray
    n_sub: int
    gemm: bool
    q_nodes: np.ndarray | None = None  # (R,) the optical-depth nodes in q

    def angles(self, t0: int, t1: int) -> slice:
        return slice(t0 * self.n_sub, t1 * self.n_sub)


def _forward_block(blk: tuple[int, int], f: _Factors, v: np.ndarray) -> np.ndarray:
    """Rates ``(D, t1 - t0)`` of the bins ``blk = (t0, t1)`` for splat weights ``v``."""
    t0, t1 = blk
    sl = f.angles(t0, t1)
    n_ang = sl.stop - sl.start
    rr = np.zeros((n_ang, f.n_w, f.n_q), dtype=f.table.dtype)
    splat, _ = _projection_kernels(f.n_q)
    splat(f.tx, f.ty, v, f.cos_a[sl], f.sin_a[sl], f.k0, f.inv_dw, rr)
    per_angle = _detect(f, sl, rr.reshape(n_ang, -1))
    return per_angle.reshape(-1, t1 - t0, f.n_sub).sum(axis=2, dtype=np.float64)


def _used_range(f: _Factors, sl: slice | np.ndarray) -> tuple[int, int]:
    """The union ``[lo, hi)`` of the used ranges of the flattened splat row over the angles
    ``sl``: the BLAS detector stage multiplies only these columns of the table.

    The splat of an angle is zero outside ``[k_lo, k_hi)`` and the gather reads nothing
    outside it, so the restricted products equal the full ones to rounding.  A block's
    angles are consecutive, so the union is hardly wider than each range.  On the wide
    field (a square, whose projection spans 0.71-1 of the table's ``w`` extent) a block uses
    0.92 of the row: the stage is 10 % faster (docs/response.md); on a narrow or
    off-centre field it skips most of the table.
    """
    lo, hi = f.k_lo[sl], f.k_hi[sl]
    if lo.size == 0:
        return 0, 0
    return int(lo.min()), int(hi.max())


def _detect(f: _Factors, sl: slice | np.ndarray, flat: np.ndarray) -> np.ndarray:
    """The detector stage: rates ``(D, n_ang)`` of splatted angles ``flat (n_ang, K R)``
    whose detector rows are those of the angles ``sl`` (a slice or indices into
    ``f.cos_a``)."""
    n_ang = flat.shape[0]
    jx, ax = f.jx[:, sl], f.ax[:, sl]
    if f.gemm:
        lo, hi = _used_range(f, sl)
        z = flat[:, lo:hi] @ f.table[:, lo:hi].T  # (n_ang, J); the splat is 0 elsewhere
        return np.sum(z[np.arange(n_ang)[None, :, None], jx] * ax, axis=2)
    per_angle = np.empty((jx.shape[0], n_ang), dtype=f.table.dtype)
    _rows_forward(f.table, flat, jx, ax, f.k_lo[sl], f.k_hi[sl], per_angle)
    return per_angle


def _detect_adjoint(f: _Factors, sl: slice | np.ndarray, ya: np.ndarray) -> np.ndarray:
    """The transpose of :func:`_detect`: splat-row weights ``(n_ang, K R)`` of data
    ``ya (D, n_ang)`` (already repeated over sub-angles)."""
    n_ang = ya.shape[1]
    jx, ax = f.jx[:, sl], f.ax[:, sl]
    if f.gemm:
        w = np.zeros((n_ang, f.table.shape[0]), dtype=f.table.dtype)
        rows = np.broadcast_to(np.arange(n_ang)[None, :, None], jx.shape)
        np.add.at(w, (rows, jx), ya[:, :, None] * ax)
        # Only the used range: the gather reads nothing outside it.
        lo, hi = _used_range(f, sl)
        gg = np.zeros((n_ang, f.table.shape[1]), dtype=f.table.dtype)
        np.matmul(w, f.table[:, lo:hi], out=gg[:, lo:hi])
        return gg
    gg = np.zeros((n_ang, f.table.shape[1]), dtype=f.table.dtype)
    _rows_adjoint(f.table, ya, jx, ax, f.k_lo[sl], f.k_hi[sl], gg)
    return gg


def _adjoint_block(blk: tuple[int, int], f: _Factors, y: np.ndarray) -> np.ndarray:
    """``sum_r acc[n, r] q_weights[n, r]`` of the bins ``blk`` for data ``y (D, n_time)``."""
    t0, t1 = blk
    sl = f.angles(t0, t1)
    n_ang = sl.stop - sl.start
    # Each sub-sample of bin t sees the bin's datum (the 1/n_sub is in ax).
    ya = np.repeat(np.ascontiguousarray(y[:, t0:t1], dtype=f.table.dtype), f.n_sub, axis=1)
    gg = _detect_adjoint(f, sl, ya)
    # In the table's type: float32 sums of a block's angles (~1e-6 relative) are far below the
    # interpolation tolerance, and the loop then does no conversions; blocks add in float64.
    acc = np.zeros((f.tx.size, f.n_q), dtype=f.table.dtype)
    # 64 chunks of pixels (the work is shared evenly by any number of threads, and the sums
    # do not depend on it); at least 256 pixels each.
    chunk = max(256, -(-f.tx.size // 64))
    _, gather = _projection_kernels(f.n_q)
    gather(f.tx, f.ty, f.cos_a[sl], f.sin_a[sl], f.k0, f.inv_dw,
           gg.reshape(n_ang, f.n_w, f.n_q), chunk, acc)
    return np.einsum("nr,nr->n", acc, f.q_weights, dtype=np.float64)


class RadonResponse(ResponseOperator):
    """The exact model's response, factorised through one table and a Radon projection.

    ``forward``/``adjoint`` cost a projection of the sky per angle (``n_sky`` work) and a
    short dot product per detector, instead of ``n_det n_sky`` profile evaluations, so fields
    of 10^6 pixels take seconds (docs/response.md).  The table is computed once, with the
    exact model, at construction.

    Parameters
    ----------
    instrument : Instrument or ResponseSpec
        The instrument, or a whole :class:`~rotmod.response.ResponseSpec` (its model must be
        ``"exact"`` and its sources at infinity; then no other field is given).
    grid : sky grid
        Any grid with ``directions()`` and ``size`` (SkyGrid, CelestialGrid, HealpixGrid).
    time_bins : TimeBinning or int
    energy : float or Quantity, optional
        Photon energy (keV); needed unless the mask has an explicit ``mu``.
    tolerance : float
        Target largest error of any profile value against the exact model (default 1e-4);
        sets the table step (error ~ step^1.5) and the number of optical-depth nodes.
    dtype : numpy dtype, optional
        float32 (default: the interpolation error, not rounding, limits the accuracy) or
        float64 (products exact to rounding; the dot test holds to ~1e-15).
    detectors : sequence of int, optional
        Subset of detectors.
    block_bins : int, optional
        Distinct time bins per block of work (default: ~64 MB of splatted angles).
    scheduler, client : optional
        Run the blocks on a Dask cluster (address or ``distributed.Client``).
    progress : bool
        tqdm bar over the blocks of each product.
    table : ndarray, optional
        The table computed earlier for the same inputs (what a stored Radon response holds,
        :func:`~rotmod.response.open_response`); checked against the shape these inputs
        give, and used instead of computing it.

    Raises
    ------
    ParameterError, MaterialError, rotmod.limits.MemoryBudgetError

    Notes
    -----
    With ``S'[n, r] = S[n] c_r(q_n)`` (Lagrange weights of the ``q`` nodes), cubic weights
    ``B_k(w)`` and linear weights ``A_j(x)``::

        forward(S)[d, t] = (1/n_sub) sum_{xi in t} sum_j A_j(delta_d(xi) mod p)
                           sum_{k, r} Psi[j, k, r] sum_n B_k(w_n(xi)) S'[n, r]

    and ``adjoint`` is its transpose.  Only the first half turn of bins is computed (a half
    turn maps the mask onto itself, ``ResponsePlan.n_distinct``).
    """

    store_kind = "radon"

    def __init__(
        self,
        instrument: Any,
        grid: Any = None,
        time_bins: Any = None,
        energy: Any = None,
        *,
        tolerance: float = DEFAULT_TOLERANCE,
        dtype: Any = None,
        detectors: Any = None,
        block_bins: int | None = None,
        scheduler: str | None = None,
        client: Any = None,
        progress: bool = False,
        table: np.ndarray | None = None,
    ) -> None:
        # The model is not a parameter: a spec given whole must name it, else it is "exact".
        model = None if isinstance(instrument, ResponseSpec) else "exact"
        spec = as_spec(instrument, grid, time_bins, model, energy, dtype=dtype,
                       detectors=detectors, default_dtype=np.float32)
        if spec.model.name != "exact" or spec.distance is not None:
            raise ParameterError(
                "spec: the Radon response factorises the exact model for sources at "
                f"infinity, got model {spec.model.name!r}, distance {spec.distance!r}")
        inst = spec.instrument
        if not inst.is_ideal:
            # The factorisation needs one mask function shared by every detector and angle
            # (docs/physics.md, section 2b): a tilted axis, a finite mask, an irregular pattern
            # or thick detectors make the table depend on the detector and the angle.
            raise ModelValidityError(
                "instrument: the Radon response describes the ideal instrument, but this one "
                f"is as built ({', '.join(inst.as_built_features())}); use operator='matrix' "
                "or a MatrixFreeResponse with the 'exact' model"
            )
        tol = as_scalar(tolerance, "tolerance", lo=0.0, lo_open=True, hi=0.1)
        self._adopt(spec)
        self.tolerance = tol
        self.scheduler, self.client, self.progress = scheduler, client, progress
        self._factors = self._setup(block_bins, table)

    @property
    def n_distinct(self) -> int:
        """A half turn maps the (ideal) mask onto itself: bins t and t + N/2 share a
        response, so only the first half of an even number of bins is computed."""
        return distinct_bins(self.n_time)

    # -- setup ---------------------------------------------------------------------------

    def _setup(self, block_bins: int | None, given: np.ndarray | None) -> _Factors:
        inst, tb, dt = self.instrument, self.time_bins, self.dtype
        mask, det = inst.mask, inst.detectors
        h, big_l = mask.thickness, mask.height
        radius, period = det.radius, mask.period
        mu = mask.linear_attenuation(self.energy)
        n_pix = self.n_sky
        check_memory(8.0 * n_pix * 6, f"the directions of {n_pix} sky pixels",
                     hint="use larger pixels or a smaller field")
        theta, phi = self.grid.directions()
        th, ph = np.asarray(theta.to_value("rad")), np.asarray(phi.to_value("rad"))
        if th.size and float(np.max(th)) >= 0.5 * np.pi:
            raise ParameterError("grid: every pixel must be above the detector plane "
                                 f"(theta < 90 deg), got {np.degrees(np.max(th)):.3g} deg")
        tan_t = np.tan(th)
        tx, ty = tan_t * np.cos(ph), tan_t * np.sin(ph)
        q = np.hypot(1.0, tan_t)
        # Interpolation step in u (cm) from the tolerance (error ~ ERROR_LAW step^1.5).
        share = 1.0 - RING_SHARE - SHIFT_SHARE
        step = (share * self.tolerance / ERROR_LAW) ** (2.0 / 3.0) * radius
        t_max = float(np.max(np.hypot(tx, ty))) if n_pix else 0.0
        # The detector stage (GEMM_ROWS): cubic in the detector offset at the full step with
        # one BLAS product, or linear at half the step (as accurate, measured) with two dot
        # products per detector and angle.
        n_x = max(4, math.ceil(period / step))
        gemm = n_x <= GEMM_ROWS * self.n_det
        if not gemm:
            n_x = max(4, math.ceil(2.0 * period / step))
        # L dw is a whole number of offset steps (at most the step), so every table value's
        # first argument x_j + L w_k is an offset node: the table is E on the offset grid
        # interpolated in s = h w alone (_table).
        ratio = 1 if gemm else 2
        dw = ratio * period / (n_x * big_l)
        k0 = math.ceil(t_max / dw) + 3
        n_w = 2 * k0 + 1
        tau_per_q = mu * h if mu != 0.0 else 0.0
        q_lo, q_hi = (float(q.min()), float(q.max())) if n_pix else (1.0, 1.0)
        if math.isinf(mu):
            tau_lo = tau_hi = math.inf
        else:
            tau_lo, tau_hi = tau_per_q * q_lo, tau_per_q * q_hi
        n_q = _ring_count(tau_lo, tau_hi, RING_SHARE * self.tolerance)
        k = np.arange(n_q)
        q_nodes = (0.5 * (q_lo + q_hi)
                   + 0.5 * (q_hi - q_lo) * np.cos(np.pi * (k + 0.5) / n_q))
        check_memory(float(n_x) * n_w * n_q * (dt.itemsize + 8),
                     f"a table of {n_x} x {n_w} x {n_q} profile values",
                     hint="raise tolerance, or use a smaller field")
        if given is None:
            tau = np.full(n_q, math.inf) if math.isinf(mu) else mu * h * q_nodes
            shifts = _shift_nodes(h * dw * np.arange(k0 + 1), self.tolerance * radius ** 1.5,
                                  mask.slat_width, mask.slat_gap)
            self._check_table_time(n_x, n_w, shifts[0], tau, mu, t_max)
            table = self._table(n_x, n_w, k0, ratio, shifts, tau, period, mu)
        else:
            table = np.ascontiguousarray(given, dtype=dt)
            if table.shape != (n_x, n_w * n_q):
                raise ParameterError(
                    f"table must have shape {(n_x, n_w * n_q)} for these inputs, got "
                    f"{table.shape}; it was computed for another instrument, grid, energy "
                    "or tolerance")
        # Angles: every sub-sample of the distinct bins, in bin order.
        xi = tb.sub_angles(0, self.n_distinct).T.ravel()  # (n_distinct * n_sub,)
        cos_a, sin_a = np.cos(xi), np.sin(xi)
        pos = det.positions
        delta = np.mod(pos[:, 0:1] * cos_a - pos[:, 1:2] * sin_a, period) * (n_x / period)
        base = np.floor(delta)
        frac = delta - base
        if gemm:
            jx = (base.astype(np.int64)[..., None] + np.arange(-1, 3)) % n_x
            ax = np.stack(_cubic(frac), axis=-1) / tb.n_sub  # the kernel's weights, on arrays
        else:
            jx = (base.astype(np.int64)[..., None] + np.arange(2)) % n_x
            ax = np.stack([1.0 - frac, frac], axis=-1) / tb.n_sub
        # Used w range per angle: w is linear in t, so its extremes over the pixels lie
        # within those over the corners of their bounding box.
        if n_pix:
            cx = np.array([tx.min(), tx.max(), tx.min(), tx.max()])
            cy = np.array([ty.min(), ty.min(), ty.max(), ty.max()])
            w_corner = cx[:, None] * cos_a - cy[:, None] * sin_a
            k_lo = (np.floor(k0 + w_corner.min(0) / dw).astype(np.int64) - 2) * n_q
            k_hi = (np.floor(k0 + w_corner.max(0) / dw).astype(np.int64) + 4) * n_q
            k_lo, k_hi = np.clip(k_lo, 0, n_w * n_q), np.clip(k_hi, 0, n_w * n_q)
        else:
            k_lo = k_hi = np.zeros(xi.size, dtype=np.int64)
        perm = _morton_order(tx, ty) if n_pix else np.zeros(0, dtype=np.int64)
        self._perm = perm
        per_bin = tb.n_sub * n_w * n_q * dt.itemsize
        if block_bins is None:
            block_bins = max(1, min(self.n_distinct, BLOCK_BYTES // max(1, per_bin)))
        block_bins = as_int(block_bins, "block_bins", 1)
        check_memory(2.0 * block_bins * per_bin + 16.0 * n_pix * n_q,
                     f"one block of {block_bins} time bins and the pixel accumulators",
                     hint="pass a smaller block_bins")
        self.blocks = [(t0, min(self.n_distinct, t0 + block_bins))
                       for t0 in range(0, self.n_distinct, block_bins)]
        return _Factors(
            table=table, n_w=n_w, n_q=n_q, k0=float(k0), inv_dw=1.0 / dw,
            tx=np.ascontiguousarray(tx[perm]), ty=np.ascontiguousarray(ty[perm]),
            q_weights=np.ascontiguousarray(_lagrange(q[perm], q_nodes), dtype=dt),
            cos_a=cos_a, sin_a=sin_a, jx=np.ascontiguousarray(jx),
            ax=np.ascontiguousarray(ax, dtype=dt), k_lo=k_lo, k_hi=k_hi,
            n_sub=tb.n_sub, gemm=gemm, q_nodes=q_nodes,
        )

    def _table(self, n_x: int, n_w: int, k0: int, ratio: int,
               shifts: tuple[np.ndarray, np.ndarray, np.ndarray], tau: np.ndarray,
               period: float, mu: float) -> np.ndarray:
        """``Psi[j, k, r] = E(x_j + L w_k, h w_k, tau_r)`` flattened to ``(J, K R)``.

        ``E`` is computed on the offset nodes ``x_i`` and the nodes ``s_m >= 0`` in the
        shadow's shift of :func:`_shift_nodes` (``J x n_s x R`` values; ~``0.15 L / h`` times
        fewer than the table's distinct values: 17x on the wide field of docs/response.md),
        and every table value is interpolated from them in ``s`` (:func:`_table_rows`).
        """
        s_nodes, node0, wts = shifts
        n_q, n_s = tau.size, s_nodes.size
        x = period / n_x * np.arange(n_x)
        coarse = np.empty((n_s, n_x, n_q))
        # About CAST_BYTES of values per call: a short call, so Ctrl-C stops the build soon.
        cols = max(1, CAST_BYTES // 8 // n_x)
        for r in range(n_q):
            for m0 in range(0, n_s, cols):
                m1 = min(n_s, m0 + cols)
                coarse[m0:m1, :, r] = _one_detector_values(
                    self.model, self.instrument, x, s_nodes[m0:m1], tau[r], mu).T
        table = np.empty((n_x, n_w, n_q), dtype=self.dtype)
        # Rows through a float64 buffer of 8 CAST_BYTES (one kernel type whatever the dtype).
        rows = max(1, (8 * CAST_BYTES) // (8 * n_w * n_q))
        buf = np.empty((min(rows, n_x), n_w, n_q))
        for j0 in range(0, n_x, rows):
            j1 = min(n_x, j0 + rows)
            _table_rows(coarse, j0, ratio, k0, node0, wts, buf[: j1 - j0])
            table[j0:j1] = buf[: j1 - j0]
        return table.reshape(n_x, n_w * n_q)

    def _check_table_time(self, n_x: int, n_w: int, s_nodes: np.ndarray, tau: np.ndarray,
                          mu: float, t_max: float) -> None:
        """Refuse a table that would take longer than the time budget, before it is made.

        A value's cost grows with the shift ``s`` of the slat shadow (8e6/s on the axis,
        1.5e6/s past a slat width, measured), so the rate is measured here: one offset at up
        to 4000 of the nodes in ``s``, evenly spread (:func:`rotmod.limits.measure_rate`: a
        few ms), at the first optical-depth node (the cost hardly depends on it).  The
        interpolation to the table's values is added at ``RATES["radon_table_values"]``.
        """
        sample = s_nodes[:: max(1, s_nodes.size // 4000)]
        per_s = measure_rate(lambda: _one_detector_values(
            self.model, self.instrument, np.zeros(1), sample, float(tau[0]), mu), sample.size)
        n_values = float(n_x) * s_nodes.size * tau.size
        seconds = n_values / per_s + float(n_x) * n_w * tau.size / RATES["radon_table_values"]
        check_time(n_values, n_values / seconds,
                   f"a Radon table from {n_x} x {s_nodes.size} x {tau.size} profile values, "
                   f"interpolated to {n_x} x {n_w} x {tau.size} (tolerance "
                   f"{self.tolerance:g}, pixels up to {np.degrees(np.arctan(t_max)):.4g} deg "
                   "from the axis)", unit="profile values",
                   hint="raise tolerance, or keep the field further from the horizon")

    # -- products --------------------------------------------------------------------------

    def _run(self, func: Any, vec: np.ndarray, factors: _Factors | None = None) -> list[Any]:
        parts: list[Any] = [None] * len(self.blocks)
        factors = self._factors if factors is None else factors
        for i, res in map_blocks(func, self.blocks, factors, vec,
                                 scheduler=self.scheduler, client=self.client,
                                 progress=self.progress, desc="radon blocks"):
            parts[i] = res
        return parts

    def _forward(self, sky: np.ndarray) -> np.ndarray:
        f = self._factors
        s = np.asarray(sky, dtype=np.float64)[self._perm]
        v = np.ascontiguousarray(s[:, None] * f.q_weights, dtype=self.dtype)
        out = np.empty((self.n_det, self.n_time))
        out[:, : self.n_distinct] = np.concatenate(self._run(_forward_block, v), axis=1)
        return repeat_half_turn(out, self.n_distinct).astype(self.dtype, copy=False)

    def _adjoint(self, counts: np.ndarray) -> np.ndarray:
        return self._adjoint_with(self._factors, counts).astype(self.dtype, copy=False)

    def _adjoint_with(self, factors: _Factors, counts: np.ndarray) -> np.ndarray:
        y = fold_half_turn(np.asarray(counts, dtype=np.float64), self.n_distinct)
        acc = np.zeros(self.n_sky)
        for part in self._run(_adjoint_block, y, factors):
            acc += part
        out = np.empty(self.n_sky)
        out[self._perm] = acc
        return out

    def adjoint_squared(self, counts: np.ndarray) -> np.ndarray:
        """``(P o P)^T Y`` through the squared table (no values of ``P`` formed).

        A value of ``P`` is a weighted sum of table entries (the interpolation), and the
        same weights on the squared table give its square to the interpolation's order
        (5e-5 relative at tolerance 1e-3, ``benchmarks/bench_tsmap_wide.py``).  With
        ``n_sub`` sub-samples per time bin it is the mean of their squares, which exceeds
        the square of their mean by their variance within the bin.  Parameters and result
        as :meth:`ResponseOperator.adjoint_squared`.
        """
        y = self._check_counts(counts)
        return self._adjoint_with(self._squared_factors, y)

    @functools.cached_property
    def _squared_factors(self) -> _Factors:
        f = self._factors
        return dataclasses.replace(f, table=np.square(f.table))

    @property
    def table(self) -> np.ndarray:
        """The table ``Psi[j, k, r]`` as ``(J, K R)`` (what a stored Radon response holds)."""
        return self._factors.table

    def columns(self, pixels: Any) -> np.ndarray:
        """``P[:, :, pixels]`` evaluated from the table (:meth:`ResponseOperator.columns`)."""
        idx = self._check_pixels(pixels)
        f = self._factors
        where = np.empty(self.n_sky, dtype=np.int64)
        where[self._perm] = np.arange(self.n_sky)  # position of each pixel in Z order
        k = where[idx]
        part = np.empty((self.n_det, self.n_distinct, idx.size), dtype=self.dtype)
        _dense(f.table, f.tx[k], f.ty[k], f.q_weights[k], f.cos_a, f.sin_a, f.k0, f.inv_dw,
               f.jx, f.ax, f.n_sub, part)
        if self.n_distinct == self.n_time:
            return part
        out = np.empty((self.n_det, self.n_time, idx.size), dtype=self.dtype)
        out[:, : self.n_distinct] = part
        return repeat_half_turn(out, self.n_distinct)

    def block(
        self, t: tuple[int, int] | None = None, n: tuple[int, int] | None = None
    ) -> np.ndarray:
        """``P[:, t0:t1, n0:n1]``: :meth:`columns` of those pixels (``None`` = whole axis)."""
        (t0, t1), (n0, n1) = block_ranges(t, n, self.n_time, self.n_sky)
        return self.columns(np.arange(n0, n1))[:, t0:t1]

    def materialise(self) -> MaterialisedResponse:
        """Every value ``P[d, t, n]`` of this operator, held in memory.

        The values are those the products use (the interpolated table), so the result's
        products equal this operator's to rounding; use it to compare with a model's exact
        response or to reuse a small response many times.

        Raises
        ------
        MemoryBudgetError
            If the matrix does not fit the memory budget.
        """
        return MaterialisedResponse(self.columns(np.arange(self.n_sky)), spec=self.spec)

    def metadata(self) -> dict[str, Any]:
        """As :meth:`ResponseOperator.metadata`, plus ``operator``: the factorisation's
        parameters (``kind`` "radon", ``tolerance``, table shape)."""
        meta = super().metadata()
        f = self._factors
        meta["operator"] = {"kind": "radon", "tolerance": self.tolerance,
                            "table": [int(f.table.shape[0]), f.n_w, f.n_q],
                            "layout": TABLE_LAYOUT}
        return meta

    def __repr__(self) -> str:
        f = self._factors
        return (super().__repr__()[:-1] + f", tolerance {self.tolerance:g}, table "
                f"{f.table.shape[0]} x {f.n_w} x {f.n_q}>")



@STORE_KINDS.register("radon")
class RadonStore(StoreKind):
    """A :class:`RadonResponse` stored as its table (metadata ``operator.kind = "radon"``);
    opens as the same operator, the table checked."""

    disk_hint = "raise tolerance or use a smaller field, or write to a disk with more space"

    @classmethod
    def estimate(cls, response: ResponseOperator) -> tuple[float, str]:
        """The table's bytes (megabytes where ``P`` would take terabytes)."""
        t = response.table
        return (float(t.nbytes),
                f"a Radon response store (a table of {t.shape[0]} x {t.shape[1]} {t.dtype.name})")

    @classmethod
    def write(cls, partial: Path, response: ResponseOperator, meta: dict[str, Any],
              chunks: tuple[int, int] | None) -> None:
        fmt.write_table(partial, meta, response.table)

    @classmethod
    def open(cls, group: Any, path: Path, meta: dict[str, Any]) -> ResponseOperator:
        layout = (meta.get("operator") or {}).get("layout", 1)
        if layout != TABLE_LAYOUT:
            # An earlier layout's grids of w differ from today's: its table would be read
            # on the wrong nodes (refused, not reinterpolated).
            raise RotmodError(f"response store {str(path)!r}: its Radon table has the grid "
                              f"layout {layout} of an earlier rotmod, this one reads layout "
                              f"{TABLE_LAYOUT}; rebuild it with rotmod response --operator "
                              "radon")
        table = fmt.read_table(group, path)
        r = restore_fields(meta)
        try:
            return RadonResponse(r["instrument"], r["grid"], r["time_bins"], r["energy"],
                                 tolerance=meta["operator"]["tolerance"], dtype=meta["dtype"],
                                 table=table)
        except (KeyError, TypeError) as exc:
            raise RotmodError(f"response store {str(path)!r}: its metadata is damaged ({exc}); "
                              "rebuild it with rotmod response") from exc
