"""What a response is computed for: one frozen, validated description.

A :class:`ResponseSpec` bundles the instrument (restricted to the selected detectors), the
sky grid, the time binning, the profile model, the energy, the sources' distance and the
dtype.  Every response operator and writer is built from one spec, so these inputs are
validated in one place (:meth:`ResponseSpec.__post_init__`), described in one place
(:meth:`ResponseSpec.to_dict`, the metadata of every response and store) and compared in one
place (:meth:`ResponseSpec.matches`, which refuses a store computed for something else).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from dataclasses import InitVar, dataclass
from typing import Any

import numpy as np

from rotmod._validate import as_distance, as_energy_scalar, as_float_dtype
from rotmod.binning import TimeBinning
from rotmod.errors import InstrumentMismatchError, ParameterError
from rotmod.geometry import Instrument
from rotmod.profiles.base import DEFAULT_MODEL, MODELS, ProfileModel, get_model
from rotmod.sky.geometry import SkyGeometry, grid_from_dict

__all__ = [
    "ResponseSpec",
    "as_spec",
    "check_field",
    "check_response_matches",
    "describe",
    "restore_fields",
]

#: The fields of a spec, in the order they are described and compared (the first differing
#: one is named).
FIELDS = ("instrument", "grid", "time_bins", "model", "energy", "dtype", "shape", "distance")


def _check_grid(grid: Any) -> Any:
    if not isinstance(grid, SkyGeometry):
        raise ParameterError(
            f"grid must be a sky grid (a rotmod.sky.SkyGeometry: SkyGrid, CelestialGrid, "
            f"HealpixGrid, ...), got {type(grid).__name__}"
        )
    return grid


def _check_instrument(instrument: Any) -> Instrument:
    if not isinstance(instrument, Instrument):
        raise ParameterError(f"instrument must be an Instrument, got {type(instrument).__name__}")
    return instrument


def _as_distance_field(distance: Any) -> float | None:
    d = as_distance(distance, 1)
    return None if np.isinf(d[0]) else float(d[0])


#: The one validator of each field of a spec (the value as the spec stores it, or
#: ParameterError naming the field, the value and the rule).
_CHECKS: dict[str, Callable[[Any], Any]] = {
    "instrument": _check_instrument,
    "grid": _check_grid,
    "time_bins": TimeBinning.coerce,
    "dtype": as_float_dtype,
    "energy": lambda e: as_energy_scalar(e, "energy"),
    "model": get_model,
    "distance": _as_distance_field,
}


def check_field(name: str, value: Any) -> Any:
    """Validate one field of a :class:`ResponseSpec` (``instrument``, ``grid``,
    ``time_bins``, ``dtype``, ``energy``, ``model``, ``distance``) and return it as a spec
    stores it; ``energy`` and ``distance`` may be ``None`` (``None`` returned).  The one
    check of each field, for the spec and for the partial metadata of a matrix from
    elsewhere (:class:`~rotmod.response.MaterialisedResponse`).

    Raises
    ------
    ParameterError
        Naming the field, the value and the rule.
    """
    if value is None and name in ("energy", "distance"):
        return None
    return _CHECKS[name](value)


def _select_detectors(instrument: Instrument, detectors: Any) -> Instrument:
    if detectors is None:
        return instrument
    idx = np.atleast_1d(np.asarray(detectors))
    n = len(instrument.detectors)
    if idx.ndim != 1 or idx.size == 0 or not np.issubdtype(idx.dtype, np.integer):
        raise ParameterError(f"detectors must be a non-empty list of indices, got {detectors!r}")
    if np.any(idx < 0) or np.any(idx >= n):
        raise ParameterError(f"detectors must be indices in [0, {n - 1}], got {idx.tolist()}")
    det = instrument.detectors.with_positions(instrument.detectors.positions[idx])
    return Instrument(instrument.mask, det, instrument.rotation_period)


@dataclass(frozen=True, eq=False)
class ResponseSpec:
    """Everything a response ``P[d, t, n]`` is computed from, validated once.

    Parameters
    ----------
    instrument : Instrument
        After construction: restricted to ``detectors`` (in that order).
    grid : sky grid
        Sky pixels (SkyGrid, CelestialGrid, HealpixGrid); ``n`` runs over
        ``grid.directions()``.
    time_bins : TimeBinning or int
        Mask-angle binning (an int means that many centre-mode bins); stored as a
        :class:`~rotmod.binning.TimeBinning`.
    model : str or ProfileModel
        Registry name or instance; stored resolved (a :class:`ProfileModel`).
    energy : float or Quantity, optional
        Photon energy (keV, > 0); stored as a float or ``None``.
    distance : float or Quantity, optional
        Sources at this distance (cm) from the origin (a lab field); ``None`` or ``inf``:
        at infinity (stored as ``None``).
    dtype : {float32, float64}
        Type of the response's values and products; stored as a numpy dtype.
    detectors : sequence of int, optional
        Indices of the detectors to include (default all).  Applied to ``instrument`` at
        construction, so it is not kept: the spec describes the response, whose
        instrument holds those detectors only.

    Raises
    ------
    ParameterError
        Naming the parameter, the value and the rule.

    Examples
    --------
    >>> from rotmod import Instrument
    >>> from rotmod.sky import SkyGrid
    >>> spec = ResponseSpec(Instrument.paper(), SkyGrid((4, 4), 1.0), 16, energy=662.0)
    >>> spec.shape[1:]
    (16, 16)
    >>> ResponseSpec.from_dict(spec.to_dict()).matches(spec)
    """

    instrument: Instrument
    grid: Any
    time_bins: TimeBinning
    model: ProfileModel = DEFAULT_MODEL  # type: ignore[assignment]  # resolved in post-init
    energy: float | None = None
    distance: float | None = None
    dtype: Any = np.float32  # stored as a numpy dtype
    detectors: InitVar[Any] = None

    def __post_init__(self, detectors: Any) -> None:
        # The order of the checks (and their messages) is that of the operators before the
        # spec existed: a call with several bad inputs names the same one.
        inst = check_field("instrument", self.instrument)
        check_field("grid", self.grid)
        tb = check_field("time_bins", self.time_bins)
        dt = check_field("dtype", self.dtype)
        inst = _select_detectors(inst, detectors)
        e = check_field("energy", self.energy)
        mdl = check_field("model", self.model)
        dist = check_field("distance", self.distance)
        for name, value in (("instrument", inst), ("time_bins", tb), ("dtype", dt),
                            ("energy", e), ("model", mdl), ("distance", dist)):
            object.__setattr__(self, name, value)

    def __eq__(self, other: object) -> bool:
        # Equal when they describe the same response (the fields' descriptions, exactly);
        # :meth:`matches` is the tolerant comparison that names what differs.
        if not isinstance(other, ResponseSpec):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    # Unhashable, like its description (nested dicts) that equality compares.
    __hash__ = None  # type: ignore[assignment]

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(n_det, n_time, n_sky)`` of the response."""
        return (len(self.instrument.detectors), self.time_bins.n_bins, int(self.grid.size))

    def replace(self, **changes: Any) -> ResponseSpec:
        """A copy with some fields changed (validated again), e.g. another grid."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """The metadata fields (plain, JSON-able values): ``instrument``, ``grid``,
        ``time_bins``, ``model`` (``describe()``), ``energy``, ``dtype``, ``shape`` and,
        only when finite, ``distance`` (so responses at infinity describe themselves as
        they always did)."""
        return describe(self.instrument, self.grid, self.time_bins, self.model, self.energy,
                        self.dtype, self.shape, self.distance)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ResponseSpec:
        """The spec a :meth:`to_dict` (or a response's metadata) describes.

        Raises
        ------
        ParameterError
            A field is missing, or the model is not one this rotmod knows.
        """
        fields = restore_fields(d)
        missing = [k for k in ("instrument", "grid", "time_bins", "model") if fields[k] is None]
        if missing:
            raise ParameterError(f"metadata must describe {', '.join(missing)} to give a "
                                 f"response spec, got {sorted(d)}")
        return cls(**fields)

    def matches(self, other: ResponseSpec | dict[str, Any]) -> None:
        """Refuse ``other`` (a spec or a stored response's metadata) unless it describes the
        same response as this spec.

        Raises
        ------
        InstrumentMismatchError
            Naming the first field that differs (e.g. ``instrument.mask.thickness``), with
            ``other``'s value as "in the store" and this spec's as "here".
        """
        stored = other.to_dict() if isinstance(other, ResponseSpec) else other
        mine = self.to_dict()
        for key in FIELDS:
            _compare(key, stored.get(key), mine.get(key))


def as_spec(
    instrument: Any,
    grid: Any = None,
    time_bins: Any = None,
    model: Any = None,
    energy: Any = None,
    *,
    dtype: Any = None,
    detectors: Any = None,
    distance: Any = None,
    default_dtype: Any = np.float32,
) -> ResponseSpec:
    """The spec of a builder's arguments: the one way every response builder takes its
    inputs, either a :class:`ResponseSpec` as the first argument (and nothing else of the
    bundle), or the instrument and the other fields (``None``: the default; ``model``
    :data:`~rotmod.profiles.DEFAULT_MODEL`, ``dtype`` ``default_dtype``).

    Raises
    ------
    ParameterError
        A spec and other fields of the bundle, or an invalid field (see
        :class:`ResponseSpec`).
    """
    if isinstance(instrument, ResponseSpec):
        given = {"grid": grid, "time_bins": time_bins, "model": model, "energy": energy,
                 "dtype": dtype, "detectors": detectors, "distance": distance}
        extra = [k for k, v in given.items() if v is not None]
        if extra:
            raise ParameterError(f"pass either a ResponseSpec or its fields, not both: got a "
                                 f"spec and {', '.join(extra)}")
        return instrument
    return ResponseSpec(instrument, grid, time_bins, DEFAULT_MODEL if model is None else model,
                        energy, distance, default_dtype if dtype is None else dtype, detectors)


def describe(
    instrument: Any,
    grid: Any,
    time_bins: Any,
    model: Any,
    energy: Any,
    dtype: Any,
    shape: tuple[int, int, int],
    distance: Any = None,
) -> dict[str, Any]:
    """The metadata fields of a response (``None`` for what is unknown), as
    :meth:`ResponseSpec.to_dict` gives them; for operators without a spec (a matrix from
    elsewhere) too."""

    def _d(obj: Any) -> Any:
        return None if obj is None else obj.to_dict()

    return {
        "instrument": _d(instrument),
        "grid": _d(grid),
        "time_bins": _d(time_bins),
        "model": None if model is None else model.describe(),
        "energy": None if energy is None else float(energy),
        "dtype": np.dtype(dtype).name,
        "shape": [int(v) for v in shape],
        # Only when finite, so that responses at infinity describe themselves as before.
        **({} if distance is None else {"distance": float(distance)}),
    }


def restore_fields(meta: dict[str, Any]) -> dict[str, Any]:
    """The objects stored metadata describes: ``instrument``, ``grid``, ``time_bins``,
    ``model``, ``energy``, ``distance`` and ``dtype`` (``None`` where absent; ``model``
    also ``None`` when it is not a model this rotmod knows with these parameters)."""
    out: dict[str, Any] = {}
    inst = meta.get("instrument")
    out["instrument"] = None if inst is None else Instrument.from_dict(inst)
    out["grid"] = None if meta.get("grid") is None else grid_from_dict(meta["grid"])
    tb = meta.get("time_bins")
    out["time_bins"] = None if tb is None else TimeBinning.from_dict(tb)
    desc = meta.get("model")
    out["model"] = None if desc is None else _restore_model(desc)
    out["energy"] = meta.get("energy")
    out["distance"] = meta.get("distance")
    out["dtype"] = np.dtype(meta.get("dtype", "float32"))
    return out


def _restore_model(desc: dict[str, Any]) -> ProfileModel | None:
    """The registered model that :meth:`ProfileModel.describe` described as ``desc``: the
    registry's entry, given the described parameters when they are not its defaults; ``None``
    for a name or parameters this rotmod does not know."""
    name = desc.get("model")
    if name not in MODELS:
        return None
    model = get_model(name)
    if model.describe() != desc:
        try:
            model = MODELS.get(name)(**{k: v for k, v in desc.items() if k != "model"})
        except TypeError:  # parameters this model does not take
            return None
    return model if model.describe() == desc else None


# ------------------------------------------------------------------------------ comparison
def _flatten(obj: Any, prefix: str) -> Iterator[tuple[str, Any]]:
    if isinstance(obj, dict):
        for k in obj:  # insertion order: the most telling field (e.g. "model") first
            yield from _flatten(obj[k], f"{prefix}.{k}" if prefix else str(k))
    elif isinstance(obj, list | tuple):
        yield f"{prefix}.len", len(obj)
        for i, v in enumerate(obj):
            yield from _flatten(v, f"{prefix}[{i}]")
    else:
        yield prefix, obj


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float | int) and isinstance(b, float | int) and not isinstance(a, bool):
        return a == b or (np.isnan(a) and np.isnan(b)) or bool(np.isclose(a, b, rtol=1e-12, atol=0))
    return a == b


def _compare(field: str, stored: Any, given: Any) -> None:
    s = dict(_flatten(stored, field))
    g = dict(_flatten(given, field))
    shared = [k for k in s if k in g]
    only = [k for k in s if k not in g] + [k for k in g if k not in s]
    for key in shared + only:
        if key not in s or key not in g or not _same(s[key], g[key]):
            raise InstrumentMismatchError(
                f"the stored response does not match: {key} is "
                f"{s.get(key, '<absent>')!r} in the store but {g.get(key, '<absent>')!r} here"
            )


def _in(unit: str) -> Callable[[Any], float]:
    def convert(value: Any) -> float:
        return float(getattr(value, "to_value", lambda _u: value)(unit))

    return convert


def _distance(value: Any) -> float | None:
    d = _in("cm")(value)
    return None if np.isinf(d) else d


#: How each field a caller may check a store against is described (as in the metadata).
_ENCODE: dict[str, Callable[[Any], Any]] = {
    "instrument": lambda v: v.to_dict(),
    "grid": lambda v: v.to_dict(),
    "time_bins": lambda v: TimeBinning.coerce(v).to_dict(),
    "model": lambda v: get_model(v).describe(),
    "energy": lambda v: as_energy_scalar(v, "energy"),
    "distance": _distance,
}


def check_response_matches(metadata: dict[str, Any], **given: Any) -> None:
    """Refuse a stored response computed for something else than the given inputs.

    Parameters
    ----------
    metadata : dict
        The stored metadata.
    **given
        Any of ``instrument``, ``grid``, ``time_bins``, ``model``, ``energy``,
        ``distance``; each one that is not ``None`` is compared with the stored one.

    Raises
    ------
    InstrumentMismatchError
        Naming the first field that differs (e.g. ``instrument.mask.thickness``).
    ParameterError
        An unknown field name.
    """
    for key in given:
        if key not in _ENCODE:
            raise ParameterError(f"expected fields must be among {sorted(_ENCODE)}, got {key!r}")
    for key, encode in _ENCODE.items():
        if given.get(key) is not None:
            _compare(key, metadata.get(key), encode(given[key]))
