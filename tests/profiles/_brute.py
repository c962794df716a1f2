"""Brute-force references for the exact model of the instrument as built.

Independent of the kernels (``rotmod.profiles._asbuilt``, ``_exact_kernels``): straight rays
traced from first principles through the tilted, offset slat slab, and fine Gauss–Legendre
quadrature (orders chosen by the caller; convergence shown by doubling them) over the
detector face -- or, for a thick detector, over its *volume*: a photon travelling toward
point ``P`` of the cylinder interacts there with density ``mu_det exp(-mu_det s(P))``, ``s``
its path inside the cylinder before ``P`` (through the top face or the side), a different
decomposition from the model's (rays labelled by their crossing of the top face's plane,
each counting ``1 - exp(-mu_det l)``).

Only the instrument's definition is shared: the mask frame is rebuilt here from the
documented convention (docs/conventions.md, "The instrument as built": the smallest rotation
taking ``z`` to the tilted axis, by scipy's rotation vectors; slat coordinates
``R_z(xi) Q (q - c_m)``), the slat pattern from ``Mask.edges`` and ``Mask.period``.

Quadrature: the integrands are smooth except on known curves -- the lines where a ray's
bottom or top crossing of the slab meets a slat edge, the disc's rim and (thick detectors)
the circle where the entry of ``P``'s ray switches from the top face to the side.  Every
line of the inner integral is cut where it meets them (the mask's by bisection, the
circles' in closed form), the outer integral where they meet the rim or each other (found
by sampling the circles and ``brentq``), and the depth where the switch circle leaves the
disc; ``y = R sin(phi)`` removes the rim's square-root singularity from the outer integral.
"""

from __future__ import annotations

import itertools
import math
import warnings

import numpy as np
from scipy.integrate import IntegrationWarning, quad
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

__all__ = ["flat_profile", "thick_profile"]


class _Setup:
    """Mask frame, slat pattern and source of one (instrument, source, mask angle)."""

    def __init__(self, inst, theta, phi, xi, distance, energy):
        m = inst.mask
        tx, ty = m.tilt_rad
        d = math.hypot(tx, ty)
        if d == 0.0:
            rot = np.eye(3)
        else:
            b = math.atan2(ty, tx)
            n = np.array([math.sin(d) * math.cos(b), math.sin(d) * math.sin(b), math.cos(d)])
            k = np.cross([0.0, 0.0, 1.0], n)
            rot = Rotation.from_rotvec(d * k / np.linalg.norm(k)).as_matrix()
        assert np.allclose(rot @ [0.0, 0.0, 1.0], n if d else [0.0, 0.0, 1.0], atol=1e-15)
        c, s = math.cos(math.radians(xi)), math.sin(math.radians(xi))
        self.M = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ rot.T
        self.cm = np.array([m.axis_offset_x, m.axis_offset_y, m.height])
        self.E = np.asarray(m.edges, dtype=float)
        self.p = m.period
        self.a = float(np.sum(self.E[1::2] - self.E[0::2]))
        self.h = m.thickness
        self.mu = m.linear_attenuation(energy) if energy is not None else m.linear_attenuation()
        t, f = math.radians(theta), math.radians(phi)
        self.dirn = np.array([math.sin(t) * math.cos(f), math.sin(t) * math.sin(f), math.cos(t)])
        self.finite = distance is not None
        self.S = distance * self.dirn if self.finite else None

    def to_source(self, X):
        """Vector from each point to the source (unnormalised for a finite distance)."""
        return self.S - X if self.finite else np.broadcast_to(self.dirn, X.shape)

    def crossings(self, X):
        """``(u_b, u_t, slab path length)`` of the rays from points ``X`` (..., 3)."""
        A = (X - self.cm) @ self.M.T
        D = self.to_source(X) @ self.M.T
        l0 = -A[..., 2] / D[..., 2]
        l1 = (self.h - A[..., 2]) / D[..., 2]
        ub = A[..., 0] + l0 * D[..., 0]
        ut = A[..., 0] + l1 * D[..., 0]
        return ub, ut, (l1 - l0) * np.linalg.norm(D, axis=-1)

    def slat_measure(self, x):
        """Slat length in ``[E[0], x]`` (``x`` >= or < ``E[0]``: signed)."""
        k = np.floor((x - self.E[0]) / self.p)
        r = x - self.E[0] - k * self.p
        tot = k * self.a
        for s0, s1 in zip(self.E[0::2], self.E[1::2], strict=True):
            tot = tot + np.clip(r - (s0 - self.E[0]), 0.0, s1 - s0)
        return tot

    def transmission(self, X):
        ub, ut, ell = self.crossings(X)
        lo, hi = np.minimum(ub, ut), np.maximum(ub, ut)
        width = hi - lo
        tiny = width < 1e-13 * self.p
        safe = np.where(tiny, 1.0, width)
        frac = (self.slat_measure(hi) - self.slat_measure(lo)) / safe
        inside = (self.slat_measure(lo + 1e-12) - self.slat_measure(lo - 1e-12)) > 1e-12
        frac = np.where(tiny, inside.astype(float), frac)
        if math.isinf(self.mu):
            return np.where(frac > 0.0, 0.0, 1.0)
        return np.exp(-self.mu * ell * frac)

    def levels(self, lo, hi):
        """Slat edges in ``[lo, hi]``."""
        out = []
        for e in self.E:
            k0 = math.floor((lo - e) / self.p)
            k1 = math.ceil((hi - e) / self.p)
            out += [e + k * self.p for k in range(k0, k1 + 1) if lo <= e + k * self.p <= hi]
        return np.array(sorted(out))


def _gl(n):
    x, w = np.polynomial.legendre.leggauss(n)
    return x, w


def _disc_integral(st, f, centre, R, depth, circle, n_out, n_in, tangent=None):
    """``∫∫ f`` over the disc ``|xy - centre| <= R`` in the plane ``z = -depth``, cut at the
    mask's kink lines and at the optional ``circle`` (centre, radius)."""
    # Local frame: x along the lab projection of the slat coordinate u (the kink lines are
    # nearly along y).
    ex = st.M[0, :2] / np.linalg.norm(st.M[0, :2])
    ey = np.array([-ex[1], ex[0]])

    def pts(x, y):
        X = np.empty((*np.broadcast(x, y).shape, 3))
        X[..., 0] = centre[0] + x * ex[0] + y * ey[0]
        X[..., 1] = centre[1] + x * ex[1] + y * ey[1]
        X[..., 2] = -depth
        return X

    def kinkfun(which):
        return lambda X: st.crossings(X)[which]

    # The levels met anywhere on the disc.
    al = np.linspace(0.0, 2.0 * math.pi, 4097)
    ring = pts(R * np.cos(al), R * np.sin(al))
    kinks = []
    for which in (0, 1):
        g = st.crossings(ring)[which]
        gc = st.crossings(pts(0.0, 0.0))[which]
        kinks.append((kinkfun(which), st.levels(min(g.min(), gc) - 1e-9, max(g.max(), gc)
                                                 + 1e-9)))
    # Outer breakpoints (in y) where the kink lines meet the rim or the circle, and where the
    # circle meets the rim or has a horizontal tangent.
    ys = [-R, R]
    curves = [(np.zeros(2), R)]
    if circle is not None:
        cc = np.array([np.dot(circle[0] - centre, ex), np.dot(circle[0] - centre, ey)])
        rc = circle[1]
        curves.append((cc, rc))
        ys += [cc[1] - rc, cc[1] + rc]
        dd = np.hypot(*cc)
        if abs(R - rc) < dd < R + rc:  # two circles' intersections
            aa = (R * R - rc * rc + dd * dd) / (2 * dd)
            hh = math.sqrt(max(R * R - aa * aa, 0.0))
            ux, uy = cc / dd
            ys += [aa * uy + hh * ux, aa * uy - hh * ux]
    if tangent is not None:  # rim points where the rays are tangent to the rim
        def tg(alpha):
            X = pts(R * np.cos(alpha), R * np.sin(alpha))
            return np.sum((X[..., :2] - centre) * tangent(X)[..., :2], axis=-1)
        g = tg(al)
        for i in np.nonzero(np.sign(g[:-1]) * np.sign(g[1:]) < 0)[0]:
            r = brentq(lambda t: float(tg(np.array(t))), al[i], al[i + 1], xtol=1e-15,
                       rtol=1e-15)
            ys.append(R * math.sin(r))
    for cen, rad in curves:
        for fun, lev in kinks:
            def on(alpha, fun=fun, cen=cen, rad=rad):
                return fun(pts(cen[0] + rad * np.cos(alpha), cen[1] + rad * np.sin(alpha)))
            g = on(al)
            for e in lev:
                d = g - e
                for i in np.nonzero(np.sign(d[:-1]) * np.sign(d[1:]) < 0)[0]:
                    r = brentq(lambda t, e=e, on=on: float(on(np.array(t))) - e, al[i],
                               al[i + 1], xtol=1e-15, rtol=1e-15)
                    ys.append(cen[1] + rad * math.sin(r))
    phis = np.unique(np.arcsin(np.clip(np.array(ys) / R, -1.0, 1.0)))
    gx, gw = _gl(n_out)
    ph = []
    wt = []
    for p1, p2 in itertools.pairwise(phis):
        if p2 - p1 < 1e-15:
            continue
        ph.append(0.5 * (p1 + p2) + 0.5 * (p2 - p1) * gx)
        wt.append(0.5 * (p2 - p1) * gw)
    ph = np.concatenate(ph)
    wt = np.concatenate(wt)
    y = R * np.sin(ph)
    half = R * np.cos(ph)
    wt = wt * half  # dy = R cos(phi) dphi
    # Inner breakpoints per line.
    cols = [-half, half]
    for fun, lev in kinks:
        if lev.size == 0:
            continue
        lo = np.broadcast_to(-half[:, None], (y.size, lev.size)).copy()
        hi = np.broadcast_to(half[:, None], (y.size, lev.size)).copy()
        yy = np.broadcast_to(y[:, None], lo.shape)
        glo = fun(pts(lo, yy)) - lev
        ghi = fun(pts(hi, yy)) - lev
        ok = glo * ghi < 0
        for _ in range(70):
            mid = 0.5 * (lo + hi)
            gm = fun(pts(mid, yy)) - lev
            left = np.sign(gm) == np.sign(glo)
            lo = np.where(left, mid, lo)
            glo = np.where(left, gm, glo)
            hi = np.where(left, hi, mid)
        cols += list(np.where(ok, 0.5 * (lo + hi), -half[:, None]).T)
    if circle is not None:
        cc, rc = curves[1]
        dy = y - cc[1]
        hw = np.sqrt(np.maximum(rc * rc - dy * dy, 0.0))
        for sg in (-1.0, 1.0):
            cols.append(np.clip(cc[0] + sg * hw, -half, half))
    br = np.sort(np.stack(cols, axis=1), axis=1)
    # x = X sin(psi) along each chord (X its half-length): regular at the rim, where the
    # path through a cylinder's side has a square-root singularity.
    hx = half[:, None]
    br = np.arcsin(np.clip(br / np.where(hx > 0, hx, 1.0), -1.0, 1.0))
    ix, iw = _gl(n_in)
    a = br[:, :-1, None]
    b = br[:, 1:, None]
    ps = 0.5 * (a + b) + 0.5 * (b - a) * ix
    xs = hx[:, :, None] * np.sin(ps)
    ws = 0.5 * (b - a) * iw * hx[:, :, None] * np.cos(ps)
    vals = f(pts(xs, y[:, None, None]))
    return float(np.sum(np.sum(vals * ws, axis=(1, 2)) * wt))


def flat_profile(inst, theta, phi, xi, *, distance=None, energy=None, n=40):
    """Profile of detector 0 (flat face): ``∫ w T / ∫ w`` over the face, ``w`` the flux
    density (``z_s / |S - q|^3`` for a source at ``S``; 1 at infinity)."""
    st = _Setup(inst, theta, phi, xi, distance, energy)
    c = np.asarray(inst.detectors.positions[0], dtype=float)
    R = inst.detectors.radius

    def w(X):
        if not st.finite:
            return np.ones(X.shape[:-1])
        r = np.linalg.norm(st.S - X, axis=-1)
        return st.S[2] / r**3

    num = _disc_integral(st, lambda X: w(X) * st.transmission(X), c, R, 0.0, None, n, n)
    den = (math.pi * R * R if not st.finite
           else _disc_integral(st, w, c, R, 0.0, None, n, n))
    return num / den


def thick_profile(inst, theta, phi, xi, *, distance=None, energy=None, n=24, n_z=None):
    """Profile of detector 0 (a cylinder of depth ``H`` below its face): ``mu_det ∫_V
    exp(-mu_det s) T w dV`` over the flux through the face, ``w = 1 / |S - P|^2`` (1 at
    infinity), ``s`` the path of ``P``'s ray inside the cylinder before ``P``."""
    st = _Setup(inst, theta, phi, xi, distance, energy)
    det = inst.detectors
    c = np.asarray(det.positions[0], dtype=float)
    R, H = det.radius, det.thickness
    mud = det.linear_attenuation(energy)

    def entry_path(X):
        dvec = st.to_source(X)
        dn = dvec / np.linalg.norm(dvec, axis=-1, keepdims=True)
        t_top = -X[..., 2] / dn[..., 2]
        px = X[..., 0] - c[0]
        py = X[..., 1] - c[1]
        aa = dn[..., 0] ** 2 + dn[..., 1] ** 2
        bb = px * dn[..., 0] + py * dn[..., 1]
        cc = px * px + py * py - R * R  # <= 0 inside
        with np.errstate(invalid="ignore", divide="ignore"):
            t_side = np.where(aa > 0, (-bb + np.sqrt(np.maximum(bb * bb - aa * cc, 0.0)))
                              / np.where(aa > 0, aa, 1.0), np.inf)
        return np.minimum(t_top, t_side)

    def integrand(X):
        v = mud * np.exp(-mud * entry_path(X)) * st.transmission(X)
        if st.finite:
            v = v / np.sum((st.S - X) ** 2, axis=-1)
        return v

    def switch_circle(z):
        """Points at depth z whose ray enters through the top rim."""
        if st.finite:
            Sz = st.S[2]
            return (c * (Sz + z) - z * st.S[:2]) / Sz, R * (Sz + z) / Sz
        return c - z * st.dirn[:2] / st.dirn[2], R

    def sep(z):
        cen, rad = switch_circle(z)
        return np.linalg.norm(cen - c) - (R + rad)

    zb = []
    if sep(H) > 0 > sep(0.0):
        zb.append(brentq(sep, 0.0, H, xtol=1e-15))

    def layer(z):
        return _disc_integral(st, integrand, c, R, z, switch_circle(z), n, n, st.to_source)

    if n_z is None:
        # Adaptive in depth: the mask's kink lines sweep across the disc as z changes, and
        # the layer integral is singular (weakly) where one meets the rim or a circle.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IntegrationWarning)
            total = quad(layer, 0.0, H, points=zb or None, epsabs=1e-13, epsrel=1e-12,
                         limit=400)[0]
    else:
        zs = [0.0, *zb, H]
        pieces = []
        for z1, z2 in itertools.pairwise(zs):
            k = max(1, math.ceil(mud * (z2 - z1) / 2.0))
            pieces += [(z1 + (z2 - z1) * i / k, z1 + (z2 - z1) * (i + 1) / k)
                       for i in range(k)]
        gz, wz = _gl(n_z)
        total = 0.0
        for z1, z2 in pieces:
            for xk, wk in zip(gz, wz, strict=True):
                total += 0.5 * (z2 - z1) * wk * layer(0.5 * (z1 + z2) + 0.5 * (z2 - z1) * xk)
    if st.finite:
        def w(X):
            r = np.linalg.norm(st.S - X, axis=-1)
            return st.S[2] / r**3
        den = _disc_integral(st, w, c, R, 0.0, None, n, n)
    else:
        den = math.pi * R * R * st.dirn[2]
    return total / den
