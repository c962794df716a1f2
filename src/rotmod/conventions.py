"""The one place for frames, signs, angle zero points and canonical units.

Every model, the Monte Carlo, the response and the reconstruction follow these rules; see
``docs/conventions.md`` for the diagram and the derivations.

Frames and units
----------------
* Canonical units inside the code: lengths in cm, angles in rad, energies in keV, times in s.
  Public functions accept `astropy.units.Quantity` everywhere; a plain number is in cm, keV
  or s, and a plain *angle* is in degrees (``rotmod._validate.as_angle``); angles that public
  objects return are Quantities (docs/conventions.md, "Units").
* Lab frame: right-handed, ``z`` up toward the sky, origin on the rotation axis in the
  detector plane ``z = 0``.  Detector faces are discs in ``z = 0``.
* The mask slab occupies ``L <= z <= L + h``.

Mask angle
----------
* At mask angle ``xi = 0`` the slats are parallel to the lab ``y`` axis and the rotation
  axis runs through the middle of a gap.
* The mask turns clockwise seen from +z.  The coordinate perpendicular to the slats of a lab
  point at polar ``(r, psi)`` (the mask-frame coordinate ``u``) is
  ``u = r cos(psi + xi) = x cos(xi) - y sin(xi)`` (the paper's ``x(t)``).
* In the mask frame the gaps are ``|u - k p| < b/2`` and the slats are
  ``b/2 + k p <= u <= b/2 + a + k p`` for every integer ``k``, with period ``p = a + b``.

Sources and photons
-------------------
* A point source at zenith ``theta`` and azimuth ``phi`` lies in the direction
  ``(sin theta cos phi, sin theta sin phi, cos theta)`` seen from the instrument; its photons
  travel along the opposite direction.
* A photon that reaches the detector plane at ``(x, y)`` crossed the mask bottom (z = L) at
  ``(x + L tan theta cos phi, y + L tan theta sin phi)`` and the mask top (z = L + h) at the
  same point plus ``h tan theta (cos phi, sin phi)``.  Its mask-frame coordinate therefore
  grows by ``s = h tan(theta) cos(xi + phi)`` from the bottom to the top face.

The instrument as built
-----------------------
(docs/conventions.md, "The instrument as built".)  A tilted, offset axis: the mask frame is
``Q (q - c_m)`` (:meth:`rotmod.geometry.Mask.frame`), ``c_m`` where the axis crosses the mask's
bottom face, ``Q`` undoing the smallest rotation from ``z`` to the axis; the rules above hold
in that frame.  A source at a finite distance ``D`` sits at ``D`` times its direction from the
origin.  A thick detector is the cylinder ``-H <= z <= 0`` below its face.

Profiles
--------
A profile value is the fraction of the photons that would reach a detector face with no
mask that reach it unattenuated (0 to 1; photopeak only, no scattering).  Count rates are
that fraction times the unobstructed rate.  With thick detectors it is the number of counts
per photon that would cross the face (the detection efficiency and side entry included, so
it may exceed 1); the sky unit stays the rate on one unobstructed face.  Profile arrays are
laid out ``[detector, angle, source]`` everywhere (the response's ``P[d, t, n]``).
"""

from __future__ import annotations

from typing import Any

import astropy.units as u
import numpy as np

from rotmod.errors import ParameterError

__all__ = [
    "ENERGY_UNIT",
    "format_quantity",
    "mask_coordinate",
    "parse_quantity",
    "shadow_shift",
    "source_angles",
    "source_direction",
]

#: The unit of every public energy given as a plain number (:func:`rotmod._validate.as_energy`).
ENERGY_UNIT = u.keV


def source_direction(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Unit vector toward a source at zenith ``theta`` and azimuth ``phi`` (rad).

    Returns an array of shape ``theta.shape + (3,)``.
    """
    theta = np.asarray(theta, dtype=float)
    phi = np.asarray(phi, dtype=float)
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def source_angles(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Zenith ``theta`` and azimuth ``phi`` (rad) of direction vectors: the inverse of
    :func:`source_direction`.

    ``direction`` has shape ``(..., 3)`` and need not be normalised; ``theta`` and ``phi`` have
    shape ``direction.shape[:-1]``.
    """
    d = np.asarray(direction, dtype=float)
    return np.arctan2(np.hypot(d[..., 0], d[..., 1]), d[..., 2]), np.arctan2(d[..., 1], d[..., 0])


def mask_coordinate(x: np.ndarray, y: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """Mask-frame coordinate perpendicular to the slats of lab point ``(x, y)`` at angle ``xi``.

    ``u = x cos(xi) - y sin(xi)``, i.e. ``r cos(psi + xi)`` for polar ``(r, psi)``.
    """
    return np.asarray(x) * np.cos(xi) - np.asarray(y) * np.sin(xi)


def shadow_shift(
    thickness: float, theta: np.ndarray, phi: np.ndarray, xi: np.ndarray
) -> np.ndarray:
    """Growth ``s`` of the mask coordinate of a ray from the mask bottom to its top face.

    ``s = h tan(theta) cos(xi + phi)``.  The seed paper prints ``h tan(theta) sin(xi - phi)``,
    which is a quarter-turn phase slip against its own ``x(t) = r cos(xi + xi0)``; see
    ``docs/physics.md``.
    """
    return thickness * np.tan(theta) * np.cos(np.asarray(xi) + np.asarray(phi))


# --------------------------------------------------------------------------- quantities as text
#
# Files and the command line write a value with its unit ("4 cm", "0.662 MeV"): one rule reads
# such text (any unit of the right kind, never a bare number) and one writes it back exactly.


def format_quantity(q: u.Quantity) -> str:
    """``q`` as text that :func:`parse_quantity` reads back to the same value exactly."""
    unit = q.unit.to_string()
    value = float(q.value)
    text = f"{value:.15g}"
    if float(text) != value:
        text = repr(value)
    return f"{text} {unit}".strip() if unit else text


def parse_quantity(
    value: Any, key: str, unit: u.UnitBase | str, what: str, *, allow_inf: bool = False
) -> u.Quantity:
    """Parse ``value`` (a string such as ``"4 cm"`` or a Quantity) as a quantity of ``unit``.

    Parameters
    ----------
    value : str or Quantity
        The value as written (in a file, on a command line).
    key : str
        Dotted key used in error messages (``"mask.slat_width"``).
    unit : str or UnitBase
        Any unit of the required physical type (``"cm"``).
    what : str
        The physical type in words (``"a length"``).
    allow_inf : bool
        Accept ``+inf`` (an opaque mask's ``mu = "inf 1/cm"``).

    Returns
    -------
    astropy.units.Quantity
        The value with its unit as written.

    Raises
    ------
    ParameterError
        Not a string with a unit, not finite, or not convertible to ``unit``.
    """
    target = u.Unit(unit)
    example = f"'1 {target.to_string()}'"
    if isinstance(value, u.Quantity):
        q = value
    elif isinstance(value, str):
        try:
            q = u.Quantity(value)
        except (TypeError, ValueError) as exc:
            raise ParameterError(
                f"{key}: must be {what} written with a unit like {example}, got {value!r}"
            ) from exc
    elif isinstance(value, bool):
        raise ParameterError(
            f"{key}: must be {what} written with a unit like {example}, got {value!r}"
        )
    elif isinstance(value, int | float):
        raise ParameterError(
            f"{key}: must be {what} written as a string with a unit like {example}, "
            f"got the bare number {value!r}"
        )
    else:
        raise ParameterError(
            f"{key}: must be {what} written with a unit like {example}, got {value!r}"
        )
    if q.isscalar is False:
        raise ParameterError(f"{key}: must be a single value, got {value!r}")
    if q.unit == u.dimensionless_unscaled and target != u.dimensionless_unscaled:
        raise ParameterError(
            f"{key}: must be {what} written with a unit like {example}, got {value!r} (no unit)"
        )
    if not q.unit.is_equivalent(target):
        raise ParameterError(
            f"{key}: must be {what} (convertible to {target.to_string()}), got {value!r}"
        )
    if not np.isfinite(q.value) and not (allow_inf and np.isposinf(q.value)):
        raise ParameterError(f"{key}: must be finite, got {value!r}")
    return q
