"""Small helpers that turn user input (floats, arrays or astropy Quantities) into canonical
float arrays and raise :class:`~rotmod.errors.ParameterError` naming the parameter.

Canonical units (see :mod:`rotmod.conventions`): cm, rad, keV, s inside the code.  At the
public surface a plain number that is an angle means *degrees* (the astropy/gammapy habit);
:func:`as_angle` is the one place that rule is applied.
"""

from __future__ import annotations

from typing import Any

import astropy.units as u
import numpy as np

from rotmod.conventions import ENERGY_UNIT
from rotmod.errors import ParameterError

__all__ = [
    "as_angle", "as_angle_scalar", "as_array", "as_distance", "as_energy", "as_energy_scalar",
    "as_float_dtype", "as_int", "as_integers", "as_scalar",
]


def _strip(value: Any, unit: u.UnitBase | None, name: str) -> np.ndarray:
    if isinstance(value, u.Quantity):
        if unit is None:
            raise ParameterError(f"{name} must be a plain number, got a Quantity {value}")
        try:
            return np.asarray(value.to_value(unit), dtype=float)
        except u.UnitConversionError as exc:
            raise ParameterError(f"{name} must be in units of {unit}, got {value.unit}") from exc
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"{name} must be numeric, got {value!r}") from exc


def _unit_text(unit: u.UnitBase | None) -> str:
    """`` cm``, `` 1/cm``, `` g/cm3``: how the unit is written in files and on the CLI."""
    if unit in (None, u.dimensionless_unscaled):
        return ""
    return " " + u.Unit(unit).to_string().replace(" / ", "/").replace(" ", "")


def _describe(arr: np.ndarray, unit: u.UnitBase | None) -> str:
    bad = arr.ravel()[0] if arr.size else arr
    return f"{bad:g}{_unit_text(unit)}"


def as_array(
    value: Any,
    name: str,
    unit: u.UnitBase | None = None,
    *,
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    hi_open: bool = False,
    ndim: int | None = None,
) -> np.ndarray:
    """Convert ``value`` to a finite float array in ``unit`` and check bounds.

    Parameters
    ----------
    value : float, array_like or `~astropy.units.Quantity`
        Plain numbers are taken to be in ``unit`` already.
    name : str
        Parameter name used in error messages.
    unit : `~astropy.units.UnitBase`, optional
        Canonical unit the value is converted to.
    lo, hi : float, optional
        Bounds (in ``unit``); ``lo_open``/``hi_open`` make them strict.
    ndim : int, optional
        Required number of dimensions (after ``np.atleast_1d`` when ``ndim == 1``).

    Returns
    -------
    numpy.ndarray
        Float array in canonical units.

    Raises
    ------
    ParameterError
        If the value is not numeric, not finite, has the wrong unit or breaks a bound.
    """
    arr = _strip(value, unit, name)
    if ndim == 1:
        arr = np.atleast_1d(arr)
    if ndim is not None and arr.ndim != ndim:
        raise ParameterError(f"{name} must be {ndim}-dimensional, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = arr[~np.isfinite(arr)]
        raise ParameterError(f"{name} must be finite, got {_describe(bad, unit)}")
    ustr = _unit_text(unit)
    if lo is not None:
        bad = arr <= lo if lo_open else arr < lo
        if np.any(bad):
            op = ">" if lo_open else ">="
            raise ParameterError(
                f"{name} must be {op} {lo:g}{ustr}, got {_describe(arr[bad], unit)}"
            )
    if hi is not None:
        bad = arr >= hi if hi_open else arr > hi
        if np.any(bad):
            op = "<" if hi_open else "<="
            raise ParameterError(
                f"{name} must be {op} {hi:g}{ustr}, got {_describe(arr[bad], unit)}"
            )
    return arr


def as_scalar(value: Any, name: str, unit: u.UnitBase | None = None, **bounds: Any) -> float:
    """Like :func:`as_array` but requires a scalar and returns a Python float."""
    arr = as_array(value, name, unit, **bounds)
    if arr.ndim != 0:
        raise ParameterError(f"{name} must be a scalar, got shape {arr.shape}")
    return float(arr)


def as_int(value: Any, name: str, lo: int = 0, hi: int | None = None) -> int:
    """Check that ``value`` is an integer (not a bool, not a float) in ``[lo, hi]``.

    Raises
    ------
    ParameterError
        Naming ``name``, the value received and the rule.
    """
    ok = not isinstance(value, bool) and isinstance(value, int | np.integer)
    if not ok or value < lo or (hi is not None and value > hi):
        rule = f"an integer >= {lo}" if hi is None else f"an integer in [{lo}, {hi}]"
        raise ParameterError(f"{name} must be {rule}, got {value!r}")
    return int(value)


def as_integers(value: Any, name: str, lo: int | None = None, hi: int | None = None
                ) -> np.ndarray:
    """Check that every element of ``value`` is an integer in ``[lo, hi]``.

    Integer arrays are taken as they are (not copied: an event list's ids may be 1e8 long);
    floats are accepted only when every one is finite and exactly integral (``2.0``: files
    often store counts and ids as floats) and returned as int64, never rounded or truncated
    (``0.7`` is refused, not read as ``0``); booleans, strings and other types are refused.

    Raises
    ------
    ParameterError
        Naming ``name``, the first offending value and the rule.
    """
    arr = np.asarray(value)
    if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer)
                                 or np.issubdtype(arr.dtype, np.floating)):
        raise ParameterError(f"{name} must hold integers, got values of type {arr.dtype}")
    if np.issubdtype(arr.dtype, np.floating):
        with np.errstate(invalid="ignore"):
            bad = ~(np.isfinite(arr) & (np.abs(arr) < 2.0**63) & (arr == np.round(arr)))
        if bad.any():
            raise ParameterError(
                f"{name} must hold integers (floats only when exactly integral), got "
                f"{arr[bad].ravel()[0]:g}")
    out = arr if np.issubdtype(arr.dtype, np.integer) else arr.astype(np.int64)
    if lo is not None and np.any(out < lo):
        raise ParameterError(f"{name} must hold integers >= {lo}, got {out[out < lo].flat[0]}")
    if hi is not None and np.any(out > hi):
        raise ParameterError(f"{name} must hold integers <= {hi}, got {out[out > hi].flat[0]}")
    return out


def as_float_dtype(dtype: Any, name: str = "dtype") -> np.dtype:
    """Check that ``dtype`` is float32 or float64 (the two precisions rotmod computes in)."""
    try:
        dt = np.dtype(dtype)
    except TypeError as exc:
        raise ParameterError(f"{name} must be float32 or float64, got {dtype!r}") from exc
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ParameterError(f"{name} must be float32 or float64, got {dt}")
    return dt


def as_angle(value: Any, name: str, **bounds: Any) -> np.ndarray:
    """Convert a public angle (Quantity, or plain number in **degrees**) to radians.

    The units rule of rotmod's public surface: every angle a user passes (zenith, azimuth,
    mask angle, phase, pixel size, roll) is an `~astropy.units.Quantity` or a plain number
    in degrees.  Bounds (``lo``, ``hi``, ``lo_open``, ``hi_open``) and ``ndim`` are those of
    :func:`as_array`, with the bounds in degrees so that error messages speak the user's unit.

    Returns
    -------
    numpy.ndarray
        The angle in radians (rotmod's internal unit).
    """
    return np.deg2rad(as_array(value, name, u.deg, **bounds))


def as_angle_scalar(value: Any, name: str, **bounds: Any) -> float:
    """Scalar form of :func:`as_angle`; returns a Python float in radians."""
    return float(np.deg2rad(as_scalar(value, name, u.deg, **bounds)))


def as_energy(value: Any, name: str, **bounds: Any) -> np.ndarray:
    """Convert a public energy (Quantity, or plain number in **keV**) to keV.

    Every energy a user passes is an `~astropy.units.Quantity` or a plain number in keV
    (:data:`rotmod.conventions.ENERGY_UNIT`).  The value must be finite and, by default,
    ``> 0 keV`` (a photon energy); ``lo``, ``hi``, ``lo_open``, ``hi_open`` (keV) and ``ndim``
    are those of :func:`as_array` and replace the default bound (``lo=None``: no lower bound).

    Returns
    -------
    numpy.ndarray
        The energy in keV.

    Raises
    ------
    ParameterError
        Naming ``name``, the value received and the rule (e.g. ``energy must be > 0 keV, got
        -1 keV``).
    """
    bounds = {"lo": 0.0, "lo_open": True, **bounds}
    return as_array(value, name, ENERGY_UNIT, **bounds)


def as_energy_scalar(value: Any, name: str, **bounds: Any) -> float:
    """Scalar form of :func:`as_energy`; returns a Python float in keV."""
    bounds = {"lo": 0.0, "lo_open": True, **bounds}
    return as_scalar(value, name, ENERGY_UNIT, **bounds)


def as_distance(value: Any, n: int, name: str = "distance") -> np.ndarray:
    """Source distances (cm; Quantities accepted), one per source or one for all: ``None``
    and ``inf`` mean a source at infinity.  Returns a float array of shape ``(n,)``.

    Raises
    ------
    ParameterError
        Not > 0 cm, NaN, or the wrong number of values.
    """
    if value is None:
        return np.full(n, np.inf)
    arr = np.atleast_1d(_strip(value, u.cm, name))
    if arr.ndim != 1:
        raise ParameterError(f"{name} must be a scalar or 1-dimensional, got shape {arr.shape}")
    if np.any(np.isnan(arr)) or np.any(arr <= 0) or np.any(np.isneginf(arr)):
        bad = arr[np.isnan(arr) | (arr <= 0)]
        raise ParameterError(f"{name} must be > 0 cm (inf: at infinity), got {bad[0]:g} cm")
    if arr.size == 1:
        return np.full(n, float(arr[0]))
    if arr.size != n:
        raise ParameterError(
            f"{name} must hold one value or one per source ({n}), got {arr.size} values"
        )
    return arr.astype(float)
