"""Mask design trade-offs: sensitivity, resolving power and transmission (the paper's Sec. 5).

With thin opaque slats the best mask has ``a = b = c``: it maximises the profile's contrast
(its standard deviation over a rotation, which is proportional to the sensitivity; Budden et
al. 2010) with no dead time.  With thick slats the shadow of a slat changes width during the
rotation (``a'(t) = a - |s(t)|``, ``b'(t) = b - |s(t)|``), partly transmits, and there is no
single best ``a`` and ``b``: one trades

* **sensitivity** -- the standard deviation of the profile over a rotation, averaged over
  the field of view and the energies of interest (larger is better);
* **resolving power** -- the geometric resolution ``arctan(b / L)`` (smaller is better);
* **transmission** -- the mean of the profile over a rotation, averaged likewise (larger is
  better: more counts, lower statistical noise per source).

:func:`scan_designs` computes these three figures of merit with the *exact* profile model
(valid for every geometry) for a grid of slat widths, gaps and (optionally) thicknesses, and
records whether each design lies inside the advanced model's validity (``min a'(t) >= 0`` and
``min b'(t) >= 0`` over the field).  :class:`DesignScan` gives the Pareto front (the designs
no other design beats on all three figures) and the best design for a stated weighting.

Sources are sampled on equal-area rings of zenith ``theta`` within the field's half-width and
``n_phi`` azimuths each; mask angles cover half a turn (profiles repeat every 180 degrees,
see :mod:`rotmod.conventions`); a single detector of diameter ``c`` sits on the axis.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_array, as_energy, as_int, as_scalar
from rotmod.errors import ModelValidityError, ParameterError
from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.limits import check_memory, check_time
from rotmod.materials import Material
from rotmod.profiles import get_model, project

if TYPE_CHECKING:
    from astropy.table import Table

__all__ = ["DesignScan", "pareto_front", "scan_designs"]

#: The figures of merit, with the direction that is better.
OBJECTIVES = {"sensitivity": "max", "transmission": "max", "resolution_deg": "min"}


def pareto_front(values: np.ndarray, maximize: np.ndarray | list[bool]) -> np.ndarray:
    """Boolean mask of the non-dominated rows of ``values``.

    Parameters
    ----------
    values : ndarray, shape (n, k)
        Figures of merit, one row per design.
    maximize : array_like of bool, shape (k,)
        For each column, whether larger is better (otherwise smaller is better).

    Returns
    -------
    numpy.ndarray of bool, shape (n,)
        True for the designs that no other design dominates (at least as good on every
        figure and strictly better on one).  Exact duplicates are all kept.
    """
    v = np.asarray(values, dtype=float)
    if v.ndim != 2:
        raise ParameterError(f"values must have shape (n, k), got {v.shape}")
    sign = np.where(np.asarray(maximize, dtype=bool), 1.0, -1.0)
    if sign.shape != (v.shape[1],):
        raise ParameterError(f"maximize must have {v.shape[1]} entries, got {sign.shape}")
    w = v * sign  # larger is better everywhere
    ge = np.all(w[:, None, :] >= w[None, :, :], axis=2)  # ge[j, i]: j at least as good as i
    gt = np.any(w[:, None, :] > w[None, :, :], axis=2)
    dominated = np.any(ge & gt, axis=0)
    return ~dominated


@dataclass
class DesignScan:
    """Figures of merit for a grid of mask designs.

    Attributes
    ----------
    slat_width, slat_gap, thickness : ndarray, shape (n,)
        ``a``, ``b``, ``h`` of each design (cm).
    sensitivity : ndarray
        Standard deviation of the profile over a rotation, averaged over field and energies.
    transmission : ndarray
        Mean of the profile over a rotation, averaged likewise.
    resolution_deg : ndarray
        ``arctan(b / L)`` (deg).
    min_a_prime, min_b_prime : ndarray
        ``a - h tan(theta_max)`` and ``b - h tan(theta_max)`` (cm) over the field.
    advanced_valid : ndarray of bool
        Whether the advanced model is valid for every source of the field.
    settings : dict
        The scan's fixed parameters (detector diameter, L, material, energies, field...).
    run_time : float
        Wall time of the scan (s).
    """

    slat_width: np.ndarray
    slat_gap: np.ndarray
    thickness: np.ndarray
    sensitivity: np.ndarray
    transmission: np.ndarray
    resolution_deg: np.ndarray
    min_a_prime: np.ndarray
    min_b_prime: np.ndarray
    advanced_valid: np.ndarray
    settings: dict[str, Any] = field(default_factory=dict)
    run_time: float = 0.0

    def __len__(self) -> int:
        return int(self.slat_width.size)

    def objectives(self) -> np.ndarray:
        """``(n, 3)`` array of sensitivity, transmission and resolution (deg)."""
        return np.column_stack([self.sensitivity, self.transmission, self.resolution_deg])

    @property
    def pareto(self) -> np.ndarray:
        """Boolean mask of the Pareto-optimal designs."""
        return pareto_front(self.objectives(), [True, True, False])

    def scores(self, weights: Any = (1.0, 1.0, 1.0)) -> np.ndarray:
        """Weighted score of every design, in [0, 1].

        Each figure is scaled to [0, 1] over the scan (best = 1; resolution is inverted so
        a smaller angle scores higher) and the scores are averaged with ``weights`` =
        (sensitivity, transmission, resolving power).
        """
        w = as_array(weights, "weights", lo=0.0, ndim=1)
        if w.shape != (3,) or w.sum() <= 0:
            raise ParameterError(
                "weights must be three numbers >= 0 (sensitivity, transmission, resolving "
                f"power) with a positive sum, got {np.asarray(weights).tolist()}"
            )
        cols = []
        for v, better in zip(self.objectives().T, OBJECTIVES.values(), strict=True):
            span = np.ptp(v)
            x = np.ones_like(v) if span == 0 else (v - v.min()) / span
            cols.append(x if better == "max" else 1.0 - x)
        return np.column_stack(cols) @ (w / w.sum())

    def best(self, weights: Any = (1.0, 1.0, 1.0), *, require_advanced: bool = False) -> int:
        """Index of the Pareto-optimal design with the highest :meth:`scores`.

        Parameters
        ----------
        weights : (float, float, float)
            Weights of sensitivity, transmission and resolving power.
        require_advanced : bool
            Only consider designs inside the advanced model's validity.

        Raises
        ------
        ParameterError
            No design qualifies.
        """
        ok = self.pareto.copy()
        if require_advanced:
            ok &= self.advanced_valid
        if not ok.any():
            raise ParameterError(
                "require_advanced: no Pareto-optimal design lies inside the advanced model's "
                "validity; widen the scan or drop the requirement"
            )
        s = np.where(ok, self.scores(weights), -np.inf)
        return int(np.argmax(s))

    def to_table(self, weights: Any = (1.0, 1.0, 1.0)) -> Table:
        """An `astropy.table.Table` with units, the Pareto flag, scores and settings in meta."""
        from astropy.table import Table  # ~90 ms; rotmod.design alone does not need it

        t = Table()
        t["slat_width"] = self.slat_width * u.cm
        t["slat_gap"] = self.slat_gap * u.cm
        t["thickness"] = self.thickness * u.cm
        t["sensitivity"] = self.sensitivity
        t["transmission"] = self.transmission
        t["resolution"] = self.resolution_deg * u.deg
        t["min_a_prime"] = self.min_a_prime * u.cm
        t["min_b_prime"] = self.min_b_prime * u.cm
        t["advanced_valid"] = self.advanced_valid
        t["pareto"] = self.pareto
        t["score"] = self.scores(weights)
        t["sensitivity"].description = "std of the profile over a rotation (FOV/energy mean)"
        t["transmission"].description = "mean of the profile over a rotation (FOV/energy mean)"
        t["resolution"].description = "arctan(b / L)"
        t.meta.update({k: v for k, v in self.settings.items()})
        t.meta["weights"] = [float(x) for x in np.ravel(weights)]
        t.meta["best_index"] = self.best(weights)
        t.meta["run_time_s"] = round(self.run_time, 3)
        return t


def _grid(value: Any, name: str, *, lo_open: bool = True) -> np.ndarray:
    arr = as_array(value, name, u.cm, lo=0.0, lo_open=lo_open, ndim=1)
    return np.unique(arr)


def scan_designs(
    *,
    detector_diameter: Any,
    height: Any,
    slat_width: Any = None,
    slat_gap: Any = None,
    thickness: Any,
    material: Any = "lead",
    energies: Any = (662.0,),
    fov: Any = 20.0,
    mu: Any = None,
    n_theta: int = 3,
    n_phi: int = 4,
    n_angles: int = 64,
    progress: Any = None,
    patterns: Any = None,
) -> DesignScan:
    """Scan mask designs and compute their figures of merit with the exact model.

    Parameters
    ----------
    detector_diameter : float or Quantity
        ``c`` (cm).
    height : float or Quantity
        ``L``, detector plane to the mask bottom (cm).
    slat_width, slat_gap, thickness : float, array_like or Quantity
        Values of ``a``, ``b`` and ``h`` to scan (cm); every combination is a design.
    material : str or Material
        Slat material (name or :class:`~rotmod.materials.Material`).
    energies : float, array_like or Quantity
        Energies of interest (keV); the figures are averaged over them.
    fov : float or Quantity
        Full width of the field of view (deg); sources fill the cone ``theta <= fov / 2``.
    mu : float or Quantity, optional
        A fixed linear attenuation coefficient (1/cm) instead of the material's.
    n_theta, n_phi : int
        Zenith rings and azimuths of the sources sampling the field.
    n_angles : int
        Mask angles over half a turn.
    progress : callable, optional
        Called as ``progress(done, total)`` after each design.
    patterns : sequence of (edges, period), optional
        Slat patterns beyond equal slats, instead of ``slat_width`` x ``slat_gap``: each is
        the slat edges of one period (cm, ``Mask.slat_edges``) and the period (cm); every
        pattern is scanned at every ``thickness``.  A design's ``slat_width`` is then its
        slat material per period and ``slat_gap`` the rest; asymmetric patterns are
        evaluated over a whole turn (``settings["patterns"]`` keeps the edges).

    Returns
    -------
    DesignScan

    Raises
    ------
    ParameterError
        Bad sizes, an empty scan, a field of view >= 180 deg, or neither (or both) of
        ``slat_width``/``slat_gap`` and ``patterns``.
    """
    t0 = time.perf_counter()
    c = as_scalar(detector_diameter, "detector_diameter", u.cm, lo=0.0, lo_open=True)
    L = as_scalar(height, "height", u.cm, lo=0.0, lo_open=True)
    if (patterns is None) == (slat_width is None or slat_gap is None) or (
            patterns is not None and (slat_width is not None or slat_gap is not None)):
        raise ParameterError(
            "give slat_width and slat_gap (equal slats), or patterns (edges and period), "
            "not both"
        )
    H = _grid(thickness, "thickness", lo_open=False)
    if patterns is None:
        A = _grid(slat_width, "slat_width")
        B = _grid(slat_gap, "slat_gap")
        shapes = [(a, b, None) for a, b in itertools.product(A, B)]
    else:
        shapes = []
        for i, pat in enumerate(patterns):
            if not isinstance(pat, tuple | list) or len(pat) != 2:
                raise ParameterError(f"patterns[{i}] must be (edges, period), got {pat!r}")
            e = as_array(pat[0], f"patterns[{i}] edges", u.cm, ndim=1)
            period = as_scalar(pat[1], f"patterns[{i}] period", u.cm, lo=0.0, lo_open=True)
            a = float(np.sum(e[1::2] - e[0::2]))
            shapes.append((a, period - a, tuple(e.tolist())))
    E = as_energy(energies, "energies", ndim=1)
    f = as_scalar(fov, "fov", u.deg, lo=0.0, hi=180.0, hi_open=True)
    for name, val in (("n_theta", n_theta), ("n_phi", n_phi), ("n_angles", n_angles)):
        as_int(val, name, 1)
    mat = material if isinstance(material, Material) else Material(str(material))
    if mu is None:
        mus = np.asarray(mat.linear_attenuation(E), dtype=float)
    else:
        opaque = not isinstance(mu, u.Quantity) and np.isposinf(float(mu))
        m = np.inf if opaque else as_scalar(mu, "mu", 1 / u.cm, lo=0.0)
        mus = np.full(E.size, m)

    # Sizes before any allocation: one design's profiles (angles x sources, float64, with the
    # projected geometry's ~4 arrays of that size) in memory, every design's in time.
    n_src = float(n_theta) * float(n_phi)
    size = (f"n_angles = {n_angles} angles x n_theta x n_phi = {n_theta} x {n_phi} sources")
    check_memory(5 * 8.0 * n_angles * n_src + 16.0 * n_src, f"a design scan of {size}",
                 hint="sample the field with fewer rings, azimuths or angles")
    check_time(float(len(shapes)) * H.size * mus.size * n_angles * n_src, "design_values",
               f"a scan of {len(shapes) * H.size} designs x {mus.size} energies x {size}",
               hint="scan fewer designs or sample the field more coarsely")

    # Sources: equal-area rings in the cone theta <= fov/2 (the first ring near the axis).
    half = np.radians(f / 2)
    k = (np.arange(n_theta) + 0.5) / n_theta
    theta_r = np.arctan(np.tan(half) * np.sqrt(k)) if f > 0 else np.zeros(n_theta)
    theta_max = float(np.arctan(np.tan(half))) if f > 0 else 0.0
    det = DetectorArray.single(c)
    exact = get_model("exact")
    advanced = get_model("advanced")

    designs = [(a, b, h, e) for (a, b, e), h in itertools.product(shapes, H)]
    n = len(designs)
    out = {k_: np.empty(n) for k_ in ("a", "b", "h", "sens", "trans", "ma", "mb")}
    valid = np.zeros(n, dtype=bool)
    for i, (a, b, h, e) in enumerate(designs):
        sens = trans = 0.0
        masks = [Mask(a, b, h, L, mat, mu=mu_e, slat_edges=e) for mu_e in mus]
        # A half turn maps a symmetric mask onto itself: half a turn of angles suffices, and
        # (theta, phi), (theta, phi + pi) give the same profile on an on-axis detector, so
        # half a turn of azimuths too; an asymmetric pattern needs the whole turn.
        turn = np.pi if masks[0].half_turn_symmetric else 2 * np.pi
        phi_r = (np.arange(n_phi) + 0.5) * (turn / n_phi)
        th, ph = (q.ravel() * u.rad for q in np.meshgrid(theta_r, phi_r, indexing="ij"))
        xi = (np.arange(n_angles) + 0.5) * (turn / n_angles) * u.rad
        for mask in masks:
            P = exact.profile(Instrument(mask, det), th, ph, xi)[0]  # (angle, source)
            sens += float(P.std(axis=0).mean())
            trans += float(P.mean())
        out["a"][i], out["b"][i], out["h"][i] = a, b, h
        out["sens"][i] = sens / mus.size
        out["trans"][i] = trans / mus.size
        smax = h * np.tan(theta_max)
        out["ma"][i], out["mb"][i] = a - smax, b - smax
        inst = Instrument(Mask(a, b, h, L, mat, mu=mus[0]), det)
        try:
            if e is not None:
                raise ModelValidityError("the advanced model takes equal slats only")
            advanced.check_validity(inst, project(inst, [theta_max] * u.rad, [0.0]))
            valid[i] = True
        except ModelValidityError:
            valid[i] = False
        if progress is not None:
            progress(i + 1, n)
    settings = {
        "detector_diameter_cm": c,
        "height_cm": L,
        "material": mat.name,
        "density_g_cm3": mat.density,
        "energies_keV": E.tolist(),
        "mu_per_cm": [float(x) for x in mus],
        "fov_deg": f,
        "n_theta": int(n_theta),
        "n_phi": int(n_phi),
        "n_angles": int(n_angles),
        "model": exact.name,
    }
    if patterns is not None:
        settings["patterns"] = [list(e) for _, _, e in shapes]
    return DesignScan(
        out["a"], out["b"], out["h"], out["sens"], out["trans"],
        np.degrees(np.arctan(out["b"] / L)), out["ma"], out["mb"], valid, settings,
        time.perf_counter() - t0,
    )
