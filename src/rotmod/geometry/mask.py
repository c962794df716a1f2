"""The rotating mask of parallel slats, as designed or as built."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_angle_scalar, as_array, as_energy, as_energy_scalar, as_scalar
from rotmod.errors import ParameterError
from rotmod.materials import Material

__all__ = ["OUTLINES", "Mask"]

#: Mask outlines: ``None`` (infinite), a disc of radius ``outline_size`` or a square of
#: half-width ``outline_size`` whose sides run along and across the slats.
OUTLINES = (None, "circle", "square")

#: Relative tolerance (of the period) for slat-edge checks and pattern symmetry.
_EDGE_RTOL = 1e-12


@dataclass(frozen=True)
class Mask:
    """A mask of parallel slats (infinite in extent) rotating about the lab z axis.

    Parameters
    ----------
    slat_width : float or Quantity
        ``a``, width of a slat (cm), >= 0.
    slat_gap : float or Quantity
        ``b``, gap between slats (cm), >= 0; ``a + b`` must be > 0.
    thickness : float or Quantity
        ``h``, slat thickness (cm), >= 0.
    height : float or Quantity
        ``L``, height of the mask's bottom face above the detector plane (cm), > 0.
    material : Material or str
        Slat material (default lead).
    mu : float or Quantity, optional
        Linear attenuation coefficient (1/cm) overriding the material at every energy;
        ``numpy.inf`` gives perfectly opaque slats, 0 transparent ones.
    slat_edges : array_like or Quantity, optional
        A non-uniform pattern: increasing slat edges ``[s0, e0, s1, e1, ...]`` (cm) in the
        mask coordinate ``u`` at mask angle 0, slat ``k`` covering ``[s_k, e_k]``; the pattern
        repeats with period ``a + b``, so the edges must span less than one period and the
        slats' widths must add up to ``a`` (the slat material per period).  Default: one
        slat ``[b/2, b/2 + a]`` per period (the gap centred on the rotation axis).
    axis_offset_x, axis_offset_y : float or Quantity
        Where the rotation axis crosses the mask's bottom face, relative to the detector
        array's centre (cm; lab x and y).  Default 0: the axis over the array centre.
    tilt_x, tilt_y : float or Quantity
        Tilt of the rotation axis (deg if plain numbers): the axis points along
        ``(sin d cos B, sin d sin B, cos d)`` with ``d = hypot(tilt_x, tilt_y)`` and
        ``B = atan2(tilt_y, tilt_x)``; the mask's faces are perpendicular to it.  At most
        10 deg (a misalignment, not a design).
    outline : {None, "circle", "square"}
        Extent of the mask: infinite (default), a disc of radius ``outline_size`` or a
        square of half-width ``outline_size`` with sides along and across the slats, both
        centred on the rotation axis and turning with the mask.  Rays that miss it are
        not attenuated.
    outline_size : float or Quantity, optional
        Radius or half-width of the outline (cm), > 0; required with an outline.

    Notes
    -----
    At mask angle 0 the slats are parallel to y and a gap is centred on the rotation axis:
    slats occupy ``b/2 + k(a+b) <= u <= b/2 + a + k(a+b)`` in the mask coordinate ``u``.
    The as-built parameters (``slat_edges``, axis offset and tilt, outline) default to the
    ideal mask, whose numbers they leave untouched; ``docs/conventions.md`` ("The instrument
    as built") defines the mask frame they set up.
    """

    # Field metadata is the one description of each field in files: ``unit`` is the unit a
    # plain number means and the unit files write (rotmod.config's TOML keys), ``fits`` and
    # ``doc`` the header card of event and profile files (rotmod.io.events: comment
    # ``[unit] doc``).  Adding a field to files is adding it here.
    slat_width: float = field(metadata={"unit": "cm", "fits": "MASK_A", "doc": "slat width a"})
    slat_gap: float = field(metadata={"unit": "cm", "fits": "MASK_B", "doc": "slat gap b"})
    thickness: float = field(metadata={"unit": "cm", "fits": "MASK_H",
                                       "doc": "slat thickness h"})
    height: float = field(metadata={"unit": "cm", "fits": "MASK_L",
                                    "doc": "mask bottom above detector plane L"})
    material: Material = field(default_factory=lambda: Material("Pb"), metadata={
        "section": "material",
        "fits": {"name": ("MASK_MAT", "slat material"), "density": ("MASK_RHO", "slat density"),
                 "mass_attenuation": ("MASK_SIG", "fixed mass attenuation")}})
    mu: float | None = field(default=None, metadata={
        "unit": "1/cm", "fits": "MASK_MU", "doc": "fixed linear attenuation", "inf": "opaque"})
    # As-built fields: files write them only when they differ from the ideal mask.
    slat_edges: tuple[float, ...] | None = field(default=None, metadata={
        "unit": "cm", "list": True, "fits": "MASK_EDG", "doc": "slat edges of one period"})
    axis_offset_x: float = field(default=0.0, metadata={
        "unit": "cm", "skip_default": True, "fits": "MASK_OX",
        "doc": "rotation axis at the mask, x"})
    axis_offset_y: float = field(default=0.0, metadata={
        "unit": "cm", "skip_default": True, "fits": "MASK_OY",
        "doc": "rotation axis at the mask, y"})
    # Held as Quantities in rad (so that dataclasses.replace cannot misread them as deg);
    # files write them in deg.
    tilt_x: Any = field(default=0.0, metadata={
        "unit": "deg", "skip_default": True, "fits": "MASK_TX",
        "doc": "tilt of the rotation axis, x"})
    tilt_y: Any = field(default=0.0, metadata={
        "unit": "deg", "skip_default": True, "fits": "MASK_TY",
        "doc": "tilt of the rotation axis, y"})
    outline: str | None = field(default=None, metadata={
        "text": True, "fits": "MASK_OUT", "doc": "mask outline (circle or square)"})
    outline_size: float | None = field(default=None, metadata={
        "unit": "cm", "fits": "MASK_OSZ", "doc": "outline radius or half-width"})

    def __post_init__(self) -> None:
        cm = u.cm
        a = as_scalar(self.slat_width, "mask.slat_width", cm, lo=0.0)
        b = as_scalar(self.slat_gap, "mask.slat_gap", cm, lo=0.0)
        if a + b <= 0:
            raise ParameterError(
                f"mask.slat_width + mask.slat_gap must be > 0 cm, got {a:g} + {b:g} cm"
            )
        h = as_scalar(self.thickness, "mask.thickness", cm, lo=0.0)
        L = as_scalar(self.height, "mask.height", cm, lo=0.0, lo_open=True)
        if L > 1e9 * (a + b):
            # The slat phase (L tan(theta) mod a + b) would keep fewer than ~6 significant
            # digits in float64: no profile computed at such a height means anything.
            raise ParameterError(
                f"mask.height must be <= 1e9 slat periods (a + b = {a + b:g} cm), got "
                f"{L:g} cm; check the unit (cm)"
            )
        object.__setattr__(self, "slat_width", a)
        object.__setattr__(self, "slat_gap", b)
        object.__setattr__(self, "thickness", h)
        object.__setattr__(self, "height", L)
        mat = self.material
        if isinstance(mat, str):
            mat = Material(mat)
        if not isinstance(mat, Material):
            raise ParameterError(f"mask.material must be a Material or a name, got {mat!r}")
        object.__setattr__(self, "material", mat)
        if self.mu is not None:
            mu = self.mu
            q = isinstance(mu, u.Quantity) and mu.unit.is_equivalent(1 / cm)
            opaque = np.isposinf(mu.to_value(1 / cm) if q else mu) if q or isinstance(
                mu, int | float | np.floating) else False
            if opaque:  # +inf: perfectly opaque slats (as_scalar refuses non-finite values)
                object.__setattr__(self, "mu", np.inf)
            else:
                object.__setattr__(self, "mu", as_scalar(mu, "mask.mu", 1 / cm, lo=0.0))
        self._check_as_built(a, b)

    def _check_as_built(self, a: float, b: float) -> None:
        """Validate and canonicalise the as-built fields (edges, axis, outline)."""
        p = a + b
        if self.slat_edges is not None:
            e = as_array(self.slat_edges, "mask.slat_edges", u.cm, ndim=1)
            tol = _EDGE_RTOL * p
            if e.size < 2 or e.size % 2:
                raise ParameterError(
                    "mask.slat_edges must hold an even number (>= 2) of edges [s0, e0, s1, "
                    f"e1, ...], got {e.size}"
                )
            if np.any(np.diff(e) <= 0):
                raise ParameterError(
                    f"mask.slat_edges must be strictly increasing, got {e.tolist()} cm"
                )
            if e[-1] - e[0] >= p - tol:
                raise ParameterError(
                    "mask.slat_edges must span less than one period (slat_width + slat_gap "
                    f"= {p:g} cm), got {e[-1] - e[0]:g} cm from {e[0]:g} to {e[-1]:g} cm"
                )
            width = float(np.sum(e[1::2] - e[0::2]))
            if abs(width - a) > 1e-9 * p:
                raise ParameterError(
                    f"mask.slat_edges must give slats whose widths add up to mask.slat_width "
                    f"= {a:g} cm (the slat material per period), got {width:.12g} cm"
                )
            object.__setattr__(self, "slat_edges", tuple(float(v) for v in e))
        for name in ("axis_offset_x", "axis_offset_y"):
            off = as_scalar(getattr(self, name), f"mask.{name}", u.cm)
            if abs(off) > 1e9 * (a + b):
                # As for the height: the slat phase would lose its precision.
                raise ParameterError(
                    f"mask.{name} must be within 1e9 slat periods (a + b = {a + b:g} cm) of "
                    f"the array's centre, got {off:g} cm; check the unit (cm)"
                )
            object.__setattr__(self, name, off)
        for name in ("tilt_x", "tilt_y"):
            t = as_angle_scalar(getattr(self, name), f"mask.{name}", lo=-10.0, hi=10.0)
            object.__setattr__(self, name, t * u.rad)
        if self.tilt > np.deg2rad(10.0):
            raise ParameterError(
                "mask.tilt_x, mask.tilt_y must tilt the axis by at most 10 deg, got "
                f"{np.rad2deg(self.tilt):g} deg"
            )
        if self.outline not in OUTLINES:
            raise ParameterError(
                f"mask.outline must be one of {list(OUTLINES)}, got {self.outline!r}"
            )
        if self.outline is None:
            if self.outline_size is not None:
                raise ParameterError(
                    "mask.outline_size needs mask.outline ('circle' or 'square'), got "
                    f"outline_size = {self.outline_size} with no outline"
                )
        else:
            if self.outline_size is None:
                raise ParameterError(
                    f"mask.outline_size (cm) is required with mask.outline = {self.outline!r}"
                )
            object.__setattr__(self, "outline_size", as_scalar(
                self.outline_size, "mask.outline_size", u.cm, lo=0.0, lo_open=True))

    @property
    def period(self) -> float:
        """Slat period ``a + b`` (cm)."""
        return self.slat_width + self.slat_gap

    @property
    def open_fraction(self) -> float:
        """Geometric open fraction ``b / (a + b)``."""
        return self.slat_gap / self.period

    @property
    def edges(self) -> np.ndarray:
        """Slat edges ``[s0, e0, s1, e1, ...]`` of one period (cm): ``slat_edges``, or the
        ideal ``[b/2, b/2 + a]``."""
        if self.slat_edges is not None:
            return np.array(self.slat_edges)
        return np.array([0.5 * self.slat_gap, 0.5 * self.slat_gap + self.slat_width])

    def frame(self) -> tuple[np.ndarray, np.ndarray]:
        """``(Q, c_m)``: the rotation from the lab to the mask frame (3 x 3) and the centre of
        the mask's bottom face (cm), where the rotation axis crosses it.

        ``Q`` is the inverse (transpose) of the smallest rotation taking the lab ``z`` axis
        to the tilted axis ``n`` (Rodrigues' formula about ``z x n``); with no tilt it is
        the identity, exactly.  At mask angle ``xi`` the slat-frame coordinates of a lab
        point ``q`` are ``R_z(xi) Q (q - c_m)``: ``u`` across the slats, ``v`` along them,
        ``z'`` above the bottom face (docs/conventions.md, "The instrument as built").
        """
        tx, ty = self.tilt_rad
        d = float(np.hypot(tx, ty))
        c_m = np.array([self.axis_offset_x, self.axis_offset_y, self.height])
        if d == 0.0:
            return np.eye(3), c_m
        k = np.array([-ty / d, tx / d, 0.0])  # unit vector along z x n
        K = np.array([[0.0, 0.0, k[1]], [0.0, 0.0, -k[0]], [-k[1], k[0], 0.0]])
        R = np.cos(d) * np.eye(3) + np.sin(d) * K + (1.0 - np.cos(d)) * np.outer(k, k)
        return np.ascontiguousarray(R.T), c_m

    def pattern(self) -> tuple[float, np.ndarray, np.ndarray, float]:
        """``(e0, W, cum, p)``: the slat pattern as the kernels take it: the first edge
        ``e0`` (cm), the edges of one period relative to it ``W`` (``W[0] = 0``), the slat
        measure from ``e0`` to each edge ``cum`` and the period ``p``."""
        E = self.edges
        W = E - E[0]
        widths = np.zeros(E.size)
        widths[1::2] = W[1::2] - W[0::2]
        return float(E[0]), W, np.cumsum(widths), self.period

    @property
    def tilt_rad(self) -> tuple[float, float]:
        """``(tilt_x, tilt_y)`` as plain floats in rad (for the kernels)."""
        return float(self.tilt_x.to_value(u.rad)), float(self.tilt_y.to_value(u.rad))

    @property
    def tilt(self) -> float:
        """Tilt of the rotation axis from the lab z axis (rad)."""
        return float(np.hypot(*self.tilt_rad))

    @property
    def is_ideal(self) -> bool:
        """True for the paper's mask: equal slats with a gap centred on the axis, the axis
        on the array centre and parallel to z, infinite extent."""
        return (self.slat_edges is None and self.axis_offset_x == 0.0
                and self.axis_offset_y == 0.0 and self.tilt == 0.0 and self.outline is None)

    @property
    def half_turn_symmetric(self) -> bool:
        """Whether a half turn maps the mask onto itself (so ``P(xi + pi) = P(xi)``).

        A half turn about the mask's own axis maps every point ``u`` of its pattern to
        ``-u``; the mask is unchanged when the slat pattern is symmetric under ``u -> -u``
        (to 1e-12 of the period).  An offset or tilted axis does not break the symmetry:
        the mask still turns about its own axis, and its outline is centred on it.
        """
        if self.slat_edges is None:
            return True
        p = self.period
        e = self.edges
        mirrored = np.sort(np.mod(-e[::-1] - e[0], p))
        own = np.sort(np.mod(e - e[0], p))
        # Compare the two patterns as sets of edges modulo the period (one rotation of the
        # list may wrap an edge from near p to near 0).
        d = np.abs(mirrored[:, None] - own[None, :])
        d = np.minimum(d, p - d)
        return bool(np.all(d.min(axis=1) <= _EDGE_RTOL * p * 10))

    def linear_attenuation(self, energy: Any = None) -> float | np.ndarray:
        """Linear attenuation coefficient of the slats (1/cm) at ``energy`` (keV): a float for
        one energy (or None), an array of ``energy``'s shape for several.

        Raises
        ------
        ParameterError
            If neither ``mu`` nor the material's mass attenuation is fixed and no energy
            is given.
        """
        if self.mu is None:  # the material checks the energy
            return self.material.coefficient(energy, "the mask's", hint=", or set mask.mu")
        # A given energy is checked even when mu is fixed: a NaN or negative energy is a
        # mistake whatever the mask.
        if energy is None:
            return float(self.mu)
        if np.ndim(energy) == 0:
            as_energy_scalar(energy, "energy")
            return float(self.mu)
        return np.full(np.shape(as_energy(energy, "energy")), float(self.mu))

    def slat_fraction(self, u0: np.ndarray) -> np.ndarray:
        """1 where mask coordinate ``u0`` lies in a slat, 0 in a gap (edges count as slat)."""
        e = self.edges
        w = np.mod(np.asarray(u0, dtype=float) - e[0], self.period)[..., None]
        inside = (w >= e[0::2] - e[0]) & (w <= e[1::2] - e[0])
        return np.any(inside, axis=-1).astype(float)

    def to_dict(self) -> dict[str, Any]:
        """Plain-number description (cm, 1/cm, g/cm3, cm2/g) for metadata and files."""
        return {
            "slat_width": self.slat_width,
            "slat_gap": self.slat_gap,
            "thickness": self.thickness,
            "height": self.height,
            "material": self.material.name,
            "density": self.material.density,
            "mass_attenuation": self.material.mass_attenuation,
            "mu": None if self.mu is None else float(self.mu),
            **self._as_built_dict(),
        }

    def _as_built_dict(self) -> dict[str, Any]:
        """The as-built fields that differ from the ideal mask (cm, deg), so that an ideal
        mask's description is unchanged (stored responses and files compare it)."""
        out: dict[str, Any] = {}
        if self.slat_edges is not None:
            out["slat_edges"] = list(self.slat_edges)
        for name in ("axis_offset_x", "axis_offset_y"):
            if getattr(self, name) != 0.0:
                out[name] = getattr(self, name)
        for name, t in zip(("tilt_x", "tilt_y"), self.tilt_rad, strict=True):
            if t != 0.0:
                out[name] = float(np.rad2deg(t))
        if self.outline is not None:
            out["outline"] = self.outline
            out["outline_size"] = self.outline_size
        return out
