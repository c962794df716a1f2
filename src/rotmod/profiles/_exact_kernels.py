"""Kernels of the exact characteristic profile (the ideal instrument), valid for every geometry.

:class:`rotmod.profiles.exact.ExactModel` calls them for the ideal instrument;
:mod:`rotmod.profiles._asbuilt` builds the instrument as built on their primitives.

Derivation (``docs/physics.md``): a ray that reaches the detector plane crosses the mask
bottom at mask coordinate ``u`` and its top at ``u + s``.  Because the coordinate is linear
in height, the ray's path in slat material is ``(h / cos theta) g(u) / |s|`` with
``g(u) = |[u, u + s] ∩ slats|`` (for ``s = 0`` the path is ``h/cos theta`` inside a slat and
0 in a gap).  Its transmission is ``T(u) = exp(-tau g(u) / |s|)``, ``tau = mu h / cos theta``,
and the profile is ``T`` averaged over the detector disc,

    P = ∫ T(u) dΦ(u),    Φ(u) = fraction of the disc (centre uc, radius R) below u.

``g`` is piecewise linear with slopes -1, 0, +1 between breakpoints at the slat edges ``e``
and at ``e - s``.  On a piece where ``g`` is constant the contribution is ``T ΔΦ`` in closed
form; where ``g`` varies (a *clip* piece) ``T`` is an exponential in ``u``.

* One-slat regime, ``|s| <= min(a, b)`` (every ray meets at most one slat; the common case):
  slat ``[e, e + a]`` shadows the footprint ``[f, f + a + |s|]``, ``f = e - max(s, 0)``, made of
  a rising clip, a full-thickness core and a falling clip, and ``P`` is a sum of closed-form
  disc fractions plus at most two clip integrals per footprint on the disc
  (:func:`_point_one_slat`; the grid kernel :func:`_row_one_slat` batches the clip
  integrals of a whole row of sources so that they vectorise).
* Otherwise (rays through two slats or across a whole slat) the kernel walks the pieces in
  order (any number of slats, detectors wider than many periods).

Clip integrals (:func:`_clip_x`, :func:`_clip_t`): with ``y`` the distance from the disc's
nearer edge in radii and ``y = t^2``, ``dΦ = (4/π) t^2 sqrt(2 - t^2) dt`` is smooth at the edge
and its only singularity, the far edge (``t = sqrt 2``), is kept outside the Bernstein ellipse
of each sub-piece; sub-pieces also limit the change of the exponent to ``_CLIP_DE``.  Each
sub-piece takes 12-point Gauss–Legendre in ``t``, or 8-point away from the edge
(``t1 >= 0.6 t2``), with ``exp`` at the nodes by a branch-free polynomial.  Node counts and
limits were chosen from the measured quadrature error (<= 1e-12 relative per sub-piece).
Parts where the exponent exceeds ``_CLIP_CUT`` (``T < 2.4e-16``) are dropped.  Measured
against adaptive quadrature over random geometries (including the hard ones of
``tests/profiles/test_exact.py``) the result is accurate to better than 1e-12; the module
claims 1e-10.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from rotmod.profiles.standard import segment_fraction

__all__ = ["exact_point", "point_edges"]

#: |s| / (a + b) below which the ray is taken as parallel to the slat walls (s = 0).
_S_ZERO = 1e-13


@njit(cache=True)
def _edge(j: int, e0: float, W: np.ndarray, p: float) -> float:
    """Slat edge number ``j`` in increasing order of the pattern whose period ``p`` has its
    edges at ``e0 + W`` (``W = [0, e0', s1', e1', ...]`` relative to the first edge ``e0``):
    even = slat start, odd = slat end."""
    n = W.size
    k = j // n
    i = j - k * n
    # For the ideal pattern (e0 = b/2, W = [0, a]) this is b/2 + k p (+ a), the rounding the
    # ideal walk always had.
    return e0 + k * p + W[i]


@njit(cache=True)
def _first_edge_above(x: float, e0: float, W: np.ndarray, p: float) -> int:
    j = W.size * math.floor((x - e0) / p)
    while _edge(j, e0, W, p) > x:
        j -= 1
    while _edge(j, e0, W, p) <= x:
        j += 1
    return j


@njit(cache=True)
def _transmission(frac: float, tau: float) -> float:
    """``exp(-tau frac)`` for path fraction ``frac`` (0..1), with the opaque limit tau = inf."""
    if frac <= 0.0:
        return 1.0
    if math.isinf(tau):
        return 0.0
    return math.exp(-tau * frac)


@njit(cache=True, inline="always")
def _cell_measure(r: float, W: np.ndarray, cum: np.ndarray) -> tuple[int, float]:
    """Where ``r`` (``0 <= r < p`` from the period's first edge) lies: the index of its
    interval (``2 j`` in slat ``j``, ``2 j - 1`` in the gap before it, the last index in the
    gap after the last slat) and the slat measure between the first edge and ``r``
    (``cum[i]``: measure up to relative edge ``W[i]``).  Slats are closed intervals."""
    n_s = W.size // 2
    for j in range(n_s):
        if r <= W[2 * j + 1]:
            lo = W[2 * j]
            if r >= lo:
                return 2 * j, cum[2 * j] + (r - lo)
            return 2 * j - 1, cum[2 * j]
    return 2 * n_s - 1, cum[W.size - 1]


@njit(cache=True)
def _path_fraction(x: float, s: float, s_abs: float, e0: float, W: np.ndarray,
                   cum: np.ndarray, p: float) -> float:
    """Fraction ``|[x, x + s] ∩ slats| / |s|`` of a ray's path through the slab in slats.

    Both ends are located in their period cell ``k`` (cell coordinate ``r`` in ``[0, p)``
    from the first edge) and the measure is ``(k2 - k1) a + M(r2) - M(r1)``, ``M`` the slat
    measure within the cell and ``a = cum[-1]`` that of a period: exactly 0 for two ends in
    one gap, exactly 1 for two ends in one slat, so no rounding noise of order eps |x| / |s|
    survives when |s| is small.
    """
    lo = min(x, x + s) - e0
    hi = max(x, x + s) - e0
    k1 = math.floor(lo / p)
    k2 = math.floor(hi / p)
    i1, m1 = _cell_measure(lo - k1 * p, W, cum)
    i2, m2 = _cell_measure(hi - k2 * p, W, cum)
    if k1 == k2 and i1 == i2:
        return 1.0 if i1 % 2 == 0 else 0.0  # both ends in one slat, or in one gap
    g = (k2 - k1) * cum[W.size - 1] + m2 - m1
    return min(max(g / s_abs, 0.0), 1.0)


# --- Clip pieces: Gauss–Legendre in t = sqrt(distance from the disc's edge) --------------
#: Gauss–Legendre rules on [-1, 1] for the clip pieces: 12 nodes in general, 8 on sub-pieces
#: away from the disc's edge (``t1 >= 0.6 t2``).
#: (Tuples, so that the kernels see the node count as a constant.)
_G12_X, _G12_W = (tuple(v) for v in np.polynomial.legendre.leggauss(12))
_G8_X, _G8_W = (tuple(v) for v in np.polynomial.legendre.leggauss(8))
#: Largest change of the exponent over one sub-piece.
_CLIP_DE = 2.5
#: Smallest Bernstein-ellipse parameter of a sub-piece in t for the density's branch point
#: at the disc's far edge, ``xi = (sqrt 2 - t_mid) / half-width``.
_CLIP_XI = 2.0
#: Exponent beyond which the clip transmission (< 2.4e-16) is dropped.
_CLIP_CUT = 36.0
_SQRT2 = math.sqrt(2.0)
_4_PI = 4.0 / math.pi
#: Contraction and reassociation only (so the 8-node loop vectorises); no NaN/inf assumptions.
_VEC = {"contract", "reassoc"}


@njit(cache=True, inline="always", fastmath=_VEC)
def _exp_neg_small(d: float) -> float:
    """``exp(-d)`` for ``|d| <= 1.25``: the degree-8 Taylor polynomial of ``exp(-d/16)``
    (relative error < 3e-16 at |d/16| <= 0.079), raised to the 16th power by four squarings
    (< 1e-14 in all, measured 7e-15).  Branch-free, so loops over it vectorise."""
    y = -0.0625 * d
    r = 1.0 / 40320.0
    r = r * y + 1.0 / 5040.0
    r = r * y + 1.0 / 720.0
    r = r * y + 1.0 / 120.0
    r = r * y + 1.0 / 24.0
    r = r * y + 1.0 / 6.0
    r = r * y + 0.5
    r = r * y + 1.0
    r = r * y + 1.0
    r = r * r
    r = r * r
    r = r * r
    return r * r


@njit(cache=True, inline="always", fastmath=_VEC, error_model="numpy")
def _gl_node(acc, x, w, tm, h, hh, ky):
    """Add Gauss–Legendre node ``x`` (weight ``w``) of :func:`_gl`."""
    dt = h * x
    t = tm + dt
    tt = t * t
    # t^2 - y_mid = 2 tm dt + dt^2 - h^2, free of cancellation.
    return acc + w * tt * math.sqrt(2.0 - tt) * _exp_neg_small(ky * (dt * (2.0 * tm + dt) - hh))


@njit(cache=True, inline="always", fastmath=_VEC, error_model="numpy")
def _gl(gx, gw, t1: float, t2: float, ky: float) -> float:
    """``∫_{t1}^{t2} t^2 sqrt(2 - t^2) exp(-ky (t^2 - y_mid)) dt`` by the Gauss–Legendre rule
    ``(gx, gw)`` (``_G8`` or ``_G12``), ``y_mid = (t1^2 + t2^2)/2`` (so ``|exponent| <= |ky|
    (t2^2 - t1^2) / 2 <= 1.25``).  The rule is a tuple, so its length is a compile-time
    constant and the node loop unrolls."""
    tm = 0.5 * (t1 + t2)
    h = 0.5 * (t2 - t1)
    hh = h * h
    acc = 0.0
    for k in range(len(gx)):
        acc = _gl_node(acc, gx[k], gw[k], tm, h, hh, ky)
    return acc * h


@njit(cache=True, inline="always")
def n_subpieces(ya: float, yb: float, de: float) -> int:
    """Number of equal sub-pieces (in ``y``) of ``[ya, yb]`` (distance from the disc's nearer
    edge, in radii) for the Gauss–Legendre rule in ``t = sqrt(y)``: the exponent may change
    by at most ``_CLIP_DE`` (it changes by ``de`` over the piece) and the far edge's branch
    point must lie outside each sub-piece's Bernstein ellipse of parameter ``_CLIP_XI``."""
    # Longest sub-piece (in y) with xi >= _CLIP_XI: for a sub-piece of length L whose mid is
    # at t, xi = 4 t (sqrt 2 - t) / L, concave in t, so the worst sub-pieces are the one at
    # the edge (t >= sqrt(L)/2, xi >= 2 sqrt(2/L) - 1) and the one at the far end (t <= tb).
    tb = math.sqrt(yb)
    ymax = 8.0 / (_CLIP_XI + 1.0) ** 2
    if tb > 0.5 * _SQRT2:
        ymax = min(ymax, 4.0 * tb * (_SQRT2 - tb) / _CLIP_XI)
    return max(math.ceil(de / _CLIP_DE), math.ceil((yb - ya) / ymax), 1)


@njit(cache=True, fastmath=_VEC, error_model="numpy")
def _clip_t(ya: float, yb: float, ea: float, ky: float) -> float:
    """``∫ exp(-(ea + ky (y - ya))) dΦ`` over ``y in [ya, yb]``, where ``y`` is the distance
    from the disc's nearer edge in radii (``0 <= ya < yb <= 1.5``).

    With ``y = t^2`` the disc density is ``dΦ = (4/π) t^2 sqrt(2 - t^2) dt``: smooth at the
    edge (t = 0); its only singularity is the far edge's branch point ``t = sqrt 2``.  The
    piece is cut into sub-pieces uniform in ``y`` such that the exponent changes by at most
    ``_CLIP_DE`` on each and the branch point lies outside the Bernstein ellipse of parameter
    ``_CLIP_XI`` around each (in t); each is integrated by 12-point Gauss–Legendre in ``t``
    (:func:`_gl` with ``_G12``), or 8-point (``_G8``) for a single sub-piece away from the edge.
    """
    dy = yb - ya
    de = abs(ky) * dy
    if de <= _CLIP_DE and dy <= 0.5 and yb <= 1.25:
        # One sub-piece (the common case): xi >= 2 holds for dy <= 0.5 when yb <= 1.25.
        scale = _4_PI * math.exp(-(ea + 0.5 * ky * dy))
        if ya >= 0.36 * yb:
            return _gl(_G8_X, _G8_W, math.sqrt(ya), math.sqrt(yb), ky) * scale
        return _gl(_G12_X, _G12_W, math.sqrt(ya), math.sqrt(yb), ky) * scale
    nsub = n_subpieces(ya, yb, de)
    step = dy / nsub
    total = 0.0
    t1 = math.sqrt(ya)
    for i in range(nsub):
        y2 = yb if i == nsub - 1 else ya + (i + 1) * step
        t2 = math.sqrt(y2)
        em = ea + ky * ((i + 0.5) * step)  # exponent at the sub-piece's mid (in y)
        if em - 0.5 * abs(ky) * step < _CLIP_CUT:
            total += _gl(_G12_X, _G12_W, t1, t2, ky) * math.exp(-em)
        t1 = t2
    return total * _4_PI


@njit(cache=True, error_model="numpy")
def _clip_x(x1: float, x2: float, e1: float, kx: float) -> float:
    """``∫ exp(-(e1 + kx (x - x1))) dΦ`` over ``x in [x1, x2]``, ``x`` the distance from the
    disc's low edge in radii (the exponent must be >= 0 on the disc).

    The parts outside the disc (``0 <= x <= 2``) and where the exponent exceeds ``_CLIP_CUT``
    are dropped; the rest is integrated by :func:`_clip_t` from the disc's nearer edge (split
    at the centre if the piece spans more than the middle half of the disc).
    """
    if x1 < 0.0:
        e1 -= kx * x1
        x1 = 0.0
    x2 = min(x2, 2.0)
    if x2 <= x1:
        return 0.0
    if x2 - x1 <= 1e-13:
        # Sliver (|s| -> 0): midpoint rule; the whole piece is < 1e-13 of the disc.
        xm = 0.5 * (x1 + x2)
        return (math.exp(-(e1 + kx * (xm - x1))) * (2.0 / math.pi)
                * math.sqrt(xm * (2.0 - xm)) * (x2 - x1))
    # Drop the part with exponent > _CLIP_CUT (it is monotonic on the piece).
    e2 = e1 + kx * (x2 - x1)
    if e1 >= _CLIP_CUT and e2 >= _CLIP_CUT:
        return 0.0
    if e1 > _CLIP_CUT:
        x1 += (_CLIP_CUT - e1) / kx
        e1 = _CLIP_CUT
    elif e2 > _CLIP_CUT:
        x2 = x1 + (_CLIP_CUT - e1) / kx
        e2 = _CLIP_CUT
    if x2 <= x1:
        return 0.0
    if x1 < 0.5 and x2 > 1.5:
        # Both halves, each from its own edge (y = x below the centre, y = 2 - x above).
        return _clip_t(x1, 1.0, e1, kx) + _clip_t(2.0 - x2, 1.0, e2, -kx)
    if x1 + x2 <= 2.0:
        return _clip_t(x1, x2, e1, kx)
    return _clip_t(2.0 - x2, 2.0 - x1, e2, -kx)


@njit(cache=True)
def _clip_integral(u1, u2, e1, e2, uc, radius):
    """∫_{u1}^{u2} exp(-E(u)) dΦ(u) for E linear from e1 at u1 to e2 at u2 (e1, e2 >= 0).

    Agrees with a converged Gauss–Legendre rule in the disc angle to ~1e-14
    (tests/profiles/test_exact.py) at a fraction of its cost: see :func:`_clip_x` and
    :func:`_clip_t`.
    """
    x1 = (u1 - (uc - radius)) / radius
    x2 = (u2 - (uc - radius)) / radius
    if x2 <= max(x1, 0.0) or x1 >= 2.0:
        return 0.0
    return _clip_x(x1, x2, e1, (e2 - e1) / (x2 - x1))


@njit(cache=True, inline="always")
def _disc_below(x: float) -> float:
    """Fraction of the disc below ``x`` diameters from its low edge (0 and 1 outside)."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    return segment_fraction(x)


@njit(cache=True, error_model="numpy")
def _point_one_slat(uc, s, s_abs, radius, a, b, tau, e_tau):
    """Profile value when no ray meets two slats (``|s| <= min(a, b)``), ``uc`` reduced.

    Slat ``[e, e + a]`` shadows the rays that cross the mask bottom in its footprint
    ``[f, f + a + |s|]``, ``f = e - max(s, 0)``: a rising clip ``[f, f + |s|]`` (exponent 0 to
    tau), a full-thickness core ``[f + |s|, f + a]`` and a falling clip ``[f + a, f + a + |s|]``
    (tau to 0); footprints do not overlap (``b >= |s|``), and rays between them are free.  So
    ``P = Φ(gaps) + e^-tau Φ(cores) + ∫_clips exp(-E) dΦ``: closed forms except for at most two
    clip integrals per slat.  Positions are in detector diameters from the disc's low edge.
    """
    p = a + b
    lo = uc - radius
    inv_c = 0.5 / radius
    pc = p * inv_c
    sc = s_abs * inv_c
    ac = a * inv_c
    # Footprint starts f = shift + k p, from the first footprint that ends above the disc's
    # low edge.
    shift = (0.5 * b - max(s, 0.0) - lo) * inv_c
    k = math.floor((-shift - ac - sc) / pc) + 1.0
    f = shift + k * pc
    clips = s_abs > 0.0 and not math.isinf(tau)
    kx = 0.5 * tau / sc if clips else 0.0  # exponent slope per radius (x = 2 * diameters)
    # Sum of non-negative transmissions (so a closed opaque mask gives exactly 0): the gap
    # before each footprint, its core and its clips; then the gap after the last one.
    prev = _disc_below(f - (pc - ac - sc))  # end of the previous footprint
    total = 0.0
    while f < 1.0:
        c1 = f + sc
        c2 = f + ac
        f2 = c2 + sc
        p_f1 = _disc_below(f)
        p_c1 = _disc_below(c1)
        p_c2 = _disc_below(c2)
        p_f2 = _disc_below(f2)
        total += (p_f1 - prev) + e_tau * (p_c2 - p_c1)
        if clips:
            if p_c1 > p_f1:
                total += _clip_x(2.0 * f, 2.0 * c1, 0.0, kx)
            if p_f2 > p_c2:
                total += _clip_x(2.0 * c2, 2.0 * f2, tau, -kx)
        prev = p_f2
        f += pc
    total += 1.0 - prev
    return min(max(total, 0.0), 1.0)


@njit(cache=True)
def exact_point(uc: float, s: float, radius: float, a: float, b: float, tau: float) -> float:
    """Exact profile value for one detector, source and mask angle.

    Parameters
    ----------
    uc : float
        Mask coordinate of the ray to the detector centre at the mask bottom (cm).
    s : float
        Growth of the ray's mask coordinate from mask bottom to top (cm).
    radius : float
        Detector radius (cm).
    a, b : float
        Slat width and gap (cm).
    tau : float
        Optical depth of a full slat along the ray, ``mu h / cos theta`` (may be inf).
    """
    if tau == 0.0 or a == 0.0:
        return 1.0
    return _point(uc, s, radius, a, b, tau, 0.0 if math.isinf(tau) else math.exp(-tau))


@njit(cache=True)
def _point(uc, s, radius, a, b, tau, e_tau):
    """:func:`exact_point` for ``tau > 0``, ``a > 0``, with ``e_tau = exp(-tau)``."""
    p = a + b
    # The mask is periodic: work near the origin so that no rounding error of size
    # eps * |uc| can swamp a small |s| (far-off-axis detectors, wide fields).
    uc = uc - p * math.floor(uc / p + 0.5)
    s_abs = abs(s)
    if s_abs <= _S_ZERO * p:
        # |s| this small moves P by O(|s| / radius) < 1e-12: use the s = 0 limit, whose
        # pieces are exact, rather than dividing rounding noise by |s|.
        s = 0.0
        s_abs = 0.0
    if s_abs <= min(a, b):
        return _point_one_slat(uc, s, s_abs, radius, a, b, tau, e_tau)
    # General case (rays through two slats or across a whole slat): walk the pieces.
    return _walk(uc, s, s_abs, radius, 0.5 * b, np.array((0.0, a)), np.array((0.0, a)), p,
                 tau)


@njit(cache=True)
def point_edges(uc, s, radius, e0, W, cum, p, tau):
    """Exact profile value of a mask of any slat pattern for one detector, source and angle.

    The pattern's period ``p`` has its slat edges at ``e0 + W`` (``W[0] = 0``, increasing,
    ``[start, end]`` pairs) and ``cum[i]`` is the slat measure from ``e0`` to ``e0 + W[i]``;
    the other arguments are those of :func:`exact_point`.
    """
    if tau == 0.0 or cum[W.size - 1] == 0.0:
        return 1.0
    uc = uc - p * math.floor(uc / p + 0.5)
    s_abs = abs(s)
    if s_abs <= _S_ZERO * p:
        s = 0.0
        s_abs = 0.0
    return _walk(uc, s, s_abs, radius, e0, W, cum, p, tau)


@njit(cache=True)
def _walk(uc, s, s_abs, radius, e0, W, cum, p, tau):
    """Walk the pieces of the disc between the breakpoints ``e`` and ``e - s`` (every slat
    edge ``e`` of the pattern ``(e0, W, p)``): closed-form disc fractions where the
    transmission is constant, clip integrals where it is an exponential in ``u``."""
    lo = uc - radius
    hi = uc + radius
    ja = _first_edge_above(lo, e0, W, p)
    ea = _edge(ja, e0, W, p)
    jb = _first_edge_above(lo + s, e0, W, p)
    eb = _edge(jb, e0, W, p) - s
    cur = lo
    phi_cur = 0.0
    total = 0.0
    while cur < hi:
        nxt = min(ea, eb, hi)
        if nxt > cur:
            # Disc fraction below nxt (acos-free polynomial form, ~1e-16).
            phi_nxt = segment_fraction(0.5 * ((nxt - uc) / radius + 1.0)) if nxt < hi else 1.0
            um = 0.5 * (cur + nxt)
            g1 = _path_fraction(cur, s, s_abs, e0, W, cum, p)
            g2 = _path_fraction(nxt, s, s_abs, e0, W, cum, p)
            if abs(g2 - g1) * s_abs <= 1e-12 * (nxt - cur + s_abs):
                gm = _path_fraction(um, s, s_abs, e0, W, cum, p)
                total += _transmission(gm, tau) * (phi_nxt - phi_cur)
            elif not math.isinf(tau):
                total += _clip_integral(cur, nxt, tau * g1, tau * g2, uc, radius)
            cur = nxt
            phi_cur = phi_nxt
        if ea <= cur:
            ja += 1
            ea = _edge(ja, e0, W, p)
        if eb <= cur:
            jb += 1
            eb = _edge(jb, e0, W, p) - s
    return min(max(total, 0.0), 1.0)


@njit(cache=True, inline="always", fastmath=_VEC)
def _exp_neg_40(e: float) -> float:
    """``exp(-e)`` for ``0 <= e <= 40``: the degree-15 Taylor polynomial of ``exp(-e/64)``
    (relative error < 3e-17), raised to the 64th power by squaring (< 3e-14 in all, measured
    2e-14).
    Branch-free, so loops over it vectorise."""
    y = e * (-1.0 / 64.0)
    r = 1.0 / 1307674368000.0
    r = r * y + 1.0 / 87178291200.0
    r = r * y + 1.0 / 6227020800.0
    r = r * y + 1.0 / 479001600.0
    r = r * y + 1.0 / 39916800.0
    r = r * y + 1.0 / 3628800.0
    r = r * y + 1.0 / 362880.0
    r = r * y + 1.0 / 40320.0
    r = r * y + 1.0 / 5040.0
    r = r * y + 1.0 / 720.0
    r = r * y + 1.0 / 120.0
    r = r * y + 1.0 / 24.0
    r = r * y + 1.0 / 6.0
    r = r * y + 0.5
    r = r * y + 1.0
    r = r * y + 1.0
    for _ in range(6):
        r = r * r
    return r


@njit(cache=True, inline="always", fastmath=_VEC, error_model="numpy")
def _piece_code(x1, x2, e1, kx):
    """A clip piece ``[x1, x2]`` (radii from the disc's low edge, exponent ``e1 + kx (x - x1)``)
    as the arguments ``(ya, yb, ea, ky)`` of a one-sub-piece :func:`_clip_t` and a code:
    0 empty, 1 for the 8-node rule, 2 for the 12-node rule, 3 needs :func:`_clip_x` (several
    sub-pieces, a split, a sliver or an exponent near the cut).  Branch-free."""
    e1 = e1 - kx * min(x1, 0.0)
    x1 = max(x1, 0.0)
    x2 = min(x2, 2.0)
    lower = x1 + x2 <= 2.0
    ya = x1 if lower else 2.0 - x2
    yb = x2 if lower else 2.0 - x1
    ea = e1 if lower else e1 + kx * (x2 - x1)
    ky = kx if lower else -kx
    dy = yb - ya
    em = ea + 0.5 * ky * dy
    ok = (dy > 1e-13) & (dy <= 0.5) & (yb <= 1.25) & (abs(ky) * dy <= _CLIP_DE) & (em <= 34.0)
    code = 0 if x2 <= x1 else (3 if not ok else (1 if ya >= 0.36 * yb else 2))
    return ya, yb, ea, ky, code


@njit(cache=True, inline="always", fastmath=_VEC, error_model="numpy")
def _gl_mass_node(acc_m, acc_t, x, w, tm, h, hh, ky):
    """Add node ``x`` (weight ``w``) of :func:`_gl_batch` to the mass and transmission sums."""
    dt = h * x
    t = tm + dt
    tt = t * t
    rho = w * tt * math.sqrt(2.0 - tt)
    return acc_m + rho, acc_t + rho * _exp_neg_small(ky * (dt * (2.0 * tm + dt) - hh))


@njit(cache=True, fastmath=_VEC, error_model="numpy")
def _gl_batch(gx, gw, ya, yb, ea, ky, amp, m, res):
    """``∫ (amp - exp(-(ea + ky (y - ya)))) dΦ`` over ``[ya, yb]`` for ``m`` one-sub-piece
    clip pieces at once, by the rule ``(gx, gw)`` of :func:`_clip_t` (vectorised across
    pieces)."""
    for i in range(m):
        t1 = math.sqrt(ya[i])
        t2 = math.sqrt(yb[i])
        tm = 0.5 * (t1 + t2)
        h = 0.5 * (t2 - t1)
        hh = h * h
        k = ky[i]
        acc_m = 0.0
        acc_t = 0.0
        for q in range(len(gx)):
            acc_m, acc_t = _gl_mass_node(acc_m, acc_t, gx[q], gw[q], tm, h, hh, k)
        em = ea[i] + 0.5 * k * (yb[i] - ya[i])
        res[i] = (amp[i] * acc_m - _exp_neg_40(em) * acc_t) * (h * _4_PI)


@njit(cache=True, error_model="numpy")
def _row_closed_forms(X, Y, Sx, Sy, e_tau, c, sn, d, radius, a, b, n_slats, opaque, w):
    """First pass of :func:`_row_one_slat`, branch-free and vectorised across sources: the
    footprints' core-side disc fractions, and each source's first footprint and ``|s|``.
    (No fastmath, so ``uc`` and ``s`` are rounded as in the per-point path; the periodic
    reduction of ``uc`` may differ from :func:`_point`'s by an ulp at a half-period tie,
    which the mask's periodicity makes harmless.)"""
    nn = X.shape[1]
    p = a + b
    inv_p = 1.0 / p
    inv_c = 0.5 / radius
    pc = p * inv_c
    ac = a * inv_c
    s_zero = _S_ZERO * p
    absorbed = w[0]
    first = w[13]
    width = w[14]
    for n in range(nn):
        uc = X[d, n] * c - Y[d, n] * sn
        s = Sx[n] * c - Sy[n] * sn
        uc = uc - p * np.floor(uc * inv_p + 0.5)
        s = 0.0 if abs(s) <= s_zero else s
        sc = abs(s) * inv_c
        shift = (0.5 * b - max(s, 0.0) - (uc - radius)) * inv_c
        first[n] = shift + (np.floor((-shift - ac - sc) / pc) + 1.0) * pc
        width[n] = sc
        absorbed[n] = 0.0
    for j in range(n_slats):
        if opaque:
            # Footprint [f, f + a + |s|] wholly absorbing.
            for n in range(nn):
                f = first[n] + j * pc
                absorbed[n] += segment_fraction(f + ac + width[n]) - segment_fraction(f)
        else:
            # (1 - e^-tau) Φ([f, f + a]); the clips' extra terms come with their quadrature.
            for n in range(nn):
                f = first[n] + j * pc
                absorbed[n] += (1.0 - e_tau[n]) * (
                    segment_fraction(f + ac) - segment_fraction(f)
                )


@njit(cache=True, error_model="numpy")
def _row_one_slat(X, Y, Sx, Sy, tau, e_tau, c, sn, d, radius, a, b, n_slats, out_row, w, iw):
    """One (detector, angle) row of :func:`_point`, vectorised across sources.

    As :func:`_point_one_slat`, but a footprint's absorption is written
    ``(1 - e^-tau) Φ([f, f + a]) + ∫_rise (e^-tau - exp(-E)) dΦ + ∫_fall (1 - exp(-E)) dΦ``,
    so only two disc fractions per footprint are needed (the clips' masses come with their
    quadrature).  Pass 1 (:func:`_row_closed_forms`) sums the disc fractions of all
    ``n_slats`` candidate footprints per source (those off the disc give exactly 0); pass 2
    compacts the clip pieces on the disc into an 8-node and a 12-node batch for
    :func:`_gl_batch` (8- and 12-node rules), which vectorise across pieces.  Pieces that need
    :func:`_clip_x` (several sub-pieces, a split, a sliver) and rays through two slats
    (``|s| > min(a, b)``) are done by the scalar code.  ``w``, ``iw``: float and int scratch,
    shapes (15, m), (2, m), ``m >= max(2 n_slats, 1) nn + 1``.  ``tau`` must be all finite
    or all inf.
    """
    nn = out_row.size
    if nn == 0:
        return
    opaque = math.isinf(tau[0])
    _row_closed_forms(X, Y, Sx, Sy, e_tau, c, sn, d, radius, a, b, n_slats, opaque, w)
    absorbed = w[0]
    first = w[13]
    width = w[14]
    pc = (a + b) * (0.5 / radius)
    ac = a * (0.5 / radius)
    s_lim = min(a, b)
    m8 = 0
    m12 = 0
    for n in range(nn):
        tn = tau[n]
        s = Sx[n] * c - Sy[n] * sn
        if tn == 0.0 or abs(s) > s_lim:
            if tn == 0.0:
                absorbed[n] = 0.0
            else:
                uc = X[d, n] * c - Y[d, n] * sn
                absorbed[n] = 1.0 - _point(uc, s, radius, a, b, tn, e_tau[n])
            continue
        sc = width[n]
        if opaque or sc == 0.0:
            continue
        kx = 0.5 * tn / sc
        et = e_tau[n]
        f = first[n]
        while f < 1.0:
            for side in range(2):
                x1 = 2.0 * f if side == 0 else 2.0 * (f + ac)
                x2 = x1 + 2.0 * sc
                if x2 <= 0.0 or x1 >= 2.0:
                    continue
                e1 = 0.0 if side == 0 else tn
                k1 = kx if side == 0 else -kx
                amp = et if side == 0 else 1.0
                ya, yb, ea, ky, code = _piece_code(x1, x2, e1, k1)
                if code == 1 or code == 2:
                    # Batch g: 0 = 8-node rule (rows 1-5 of w), 1 = 12-node (rows 7-11).
                    g = code - 1
                    r = 1 + 6 * g
                    q = m8 if g == 0 else m12
                    w[r, q] = ya
                    w[r + 1, q] = yb
                    w[r + 2, q] = ea
                    w[r + 3, q] = ky
                    w[r + 4, q] = amp
                    iw[g, q] = n
                    if g == 0:
                        m8 += 1
                    else:
                        m12 += 1
                elif code == 3:
                    mass = _disc_below(0.5 * x2) - _disc_below(0.5 * x1)
                    absorbed[n] += amp * mass - _clip_x(x1, x2, e1, k1)
            f += pc
    _gl_batch(_G8_X, _G8_W, w[1], w[2], w[3], w[4], w[5], m8, w[6])
    _gl_batch(_G12_X, _G12_W, w[7], w[8], w[9], w[10], w[11], m12, w[12])
    res8 = w[6]
    res12 = w[12]
    own8 = iw[0]
    own12 = iw[1]
    for i in range(m8):
        absorbed[own8[i]] += res8[i]
    for i in range(m12):
        absorbed[own12[i]] += res12[i]
    for n in range(nn):
        out_row[n] = min(max(1.0 - absorbed[n], 0.0), 1.0)


def _exact_grid(X, Y, Sx, Sy, tau, cos_xi, sin_xi, radius, a, b, out):
    """``out[d, t, n]``: the row kernel, or the per-point kernel where the rows do not apply
    (``b = 0``, where only ``s = 0`` is one-slat; and a mix of opaque and finite optical
    depths).  Two kernels chosen here rather than two branches of one: the per-point one
    is compiled only where it is used (a first run compiles ~1 s less)."""
    nd, nt, nn = out.shape
    if a == 0.0:
        out[...] = 1.0
        return
    n_inf = int(np.count_nonzero(np.isinf(tau)))
    if b == 0.0 or nd * nt == 0 or 0 < n_inf < nn:
        _exact_points(X, Y, Sx, Sy, tau, cos_xi, sin_xi, radius, a, b, out)
    else:
        _exact_rows(X, Y, Sx, Sy, tau, cos_xi, sin_xi, radius, a, b, out)


@njit(parallel=True, cache=True)
def _exact_points(X, Y, Sx, Sy, tau, cos_xi, sin_xi, radius, a, b, out):
    """The per-point kernel of :func:`_exact_grid`."""
    nd, nt, nn = out.shape
    e_tau = np.exp(-tau)
    for idx in prange(nd * nt):
        d = idx // nt
        t = idx % nt
        c = cos_xi[t]
        sn = sin_xi[t]
        for n in range(nn):
            uc = X[d, n] * c - Y[d, n] * sn
            s = Sx[n] * c - Sy[n] * sn
            out[d, t, n] = (
                1.0 if tau[n] == 0.0
                else _point(uc, s, radius, a, b, tau[n], e_tau[n])
            )


@njit(parallel=True, cache=True)
def _exact_rows(X, Y, Sx, Sy, tau, cos_xi, sin_xi, radius, a, b, out):
    """The row kernel of :func:`_exact_grid` (:func:`_row_one_slat` per row)."""
    nd, nt, nn = out.shape
    e_tau = np.exp(-tau)
    rows = nd * nt
    # At most floor((c + a + |s|) / p) + 1 footprints meet the disc, |s| <= min(a, b), each
    # with two clip pieces.
    n_slats = math.floor((2.0 * radius + a + min(a, b)) / (a + b)) + 1
    m = 2 * n_slats * nn + 1
    n_chunks = min(rows, 64)
    for ch in prange(n_chunks):
        w = np.empty((15, m))
        iw = np.empty((2, m), dtype=np.int64)
        for idx in range(ch * rows // n_chunks, (ch + 1) * rows // n_chunks):
            d = idx // nt
            t = idx % nt
            _row_one_slat(X, Y, Sx, Sy, tau, e_tau, cos_xi[t], sin_xi[t], d, radius, a, b,
                          n_slats, out[d, t], w, iw)
