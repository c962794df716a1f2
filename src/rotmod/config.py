"""Instrument description files: typed, validated, unit-aware, round-tripping to TOML.

An instrument file is TOML (YAML is accepted too, with the same schema) with explicit units
written as strings and parsed by `astropy.units`::

    name = "paper"
    description = "The seed paper's simulation instrument"
    rotation_period = "60 s"
    energies = ["122 keV", "662 keV"]

    [mask]
    slat_width = "4 cm"      # a
    slat_gap = "4 cm"        # b
    thickness = "2 cm"       # h
    height = "100 cm"        # L, detector plane to the mask's bottom face
    # mu = "1.17 1/cm"       # optional: linear attenuation overriding the material

    [material]
    name = "lead"
    # density = "11.34 g/cm3"            # optional for elements: the database's value
    # mass_attenuation = "0.103 cm2/g"   # optional: fixed at every energy

    [detectors]
    layout = "single"        # or "list" (positions = [["0 cm", "0 cm"], ...]) or "hexagonal"
    diameter = "4 cm"
    x0 = "0 cm"
    y0 = "0 cm"
    # hexagonal: rings = 2, pitch = "3.99 cm"
    # thickness = "2.5 cm"   # optional: cylinders of [detector_material] (default: flat faces)

The instrument as built (all optional; docs/conventions.md, "The instrument as built")::

    [mask]
    axis_offset_x = "1 mm"   # where the rotation axis meets the mask's bottom face
    axis_offset_y = "0 mm"
    tilt_x = "0.2 deg"       # tilt of the rotation axis
    tilt_y = "0 deg"
    outline = "circle"       # or "square"; the mask's extent
    outline_size = "40 cm"   # radius, or half-width of the square
    slat_edges = ["1 cm", "3 cm", "4 cm", "7 cm"]   # a non-uniform pattern (one period)

    [detector_material]      # required with detectors.thickness
    name = "NaI"
    density = "3.67 g/cm3"

A file may start from a preset or another file with ``extends = "prototype"`` and give only
what differs (tables merge key by key): the presets stay the one description of each named
instrument.

The tables are the :class:`~rotmod.geometry.Mask`, :class:`~rotmod.materials.Material` and
:class:`~rotmod.geometry.Instrument` dataclasses written with units: their fields (and the unit
of each, from the field's ``metadata``) are the file's keys.  Reading converts the strings to
Quantities and builds the :class:`~rotmod.geometry.Instrument` directly, so each value is
validated once, by the model; an error names the key, the value and the rule
(``mask.slat_width: must be >= 0 cm, got -4 cm``) and unknown keys are refused with the
closest allowed spelling suggested.  :class:`InstrumentConfig` is that instrument plus what
only a file carries (energies of interest, name, description); it writes back (in cm, s,
keV; detectors as a single position or a list) to a file that loads to an equal
configuration.

Presets ship with the package (``rotmod/presets/*.toml``): ``paper`` and ``prototype``;
:func:`rotmod.io.load_instrument` accepts a preset name or a path.

This module is the schema only.  The files themselves (reading TOML/YAML, ``extends``, the
presets, writing with tomli-w) are :mod:`rotmod.io.config`'s, registered with
:func:`rotmod.io.read`/:func:`rotmod.io.write`; ``rotmod.config.load_instrument`` (and
``load_instrument_config``, ``list_presets``, ``preset_path``) are deprecated aliases of
those in :mod:`rotmod.io`.  Quantities written as text
follow one rule, :func:`rotmod.conventions.parse_quantity` (its ParameterError becomes a
:class:`ConfigError` here).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import astropy.units as u
import numpy as np

from rotmod.conventions import format_quantity as _fmt_q
from rotmod.conventions import parse_quantity
from rotmod.errors import MaterialError, ParameterError, RotmodError
from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.materials import DATABASE_RANGE_KEV, Material

__all__ = ["ConfigError", "InstrumentConfig"]

_LAYOUTS = ("single", "list", "hexagonal")
#: Keys each detector layout takes.
_PER_LAYOUT = {
    "single": ("layout", "diameter", "x0", "y0"),
    "list": ("layout", "diameter", "positions"),
    "hexagonal": ("layout", "diameter", "rings", "pitch"),
}


class ConfigError(ParameterError):
    """An instrument file is unreadable, has an unknown key or a value that breaks a rule."""


# --------------------------------------------------------------------------- helpers


def _check_bound(
    q: u.Quantity, key: str, unit: str, *, lo: float, strict: bool, original: Any = None
) -> None:
    v = q.to_value(unit)
    if (v <= lo) if strict else (v < lo):
        op = ">" if strict else ">="
        got = original if isinstance(original, str) else _fmt_q(q)
        raise ConfigError(f"{key}: must be {op} {lo:g} {unit}, got {got}")


def _quantity(
    d: dict[str, Any], name: str, section: str, unit: str, what: str, *, lo: float = 0.0,
    strict: bool = True, required: bool = True,
) -> u.Quantity | None:
    key = f"{section}.{name}" if section else name
    if name not in d:
        if required:
            raise ConfigError(f"{key}: is required ({what}, e.g. '1 {unit}'), but it is missing")
        return None
    q = parse_quantity(d[name], key, unit, what)
    _check_bound(q, key, unit, lo=lo, strict=strict, original=d[name])
    return q


def _check_keys(d: Any, allowed: tuple[str, ...], section: str) -> dict[str, Any]:
    where = section or "the instrument file"
    if not isinstance(d, dict):
        raise ConfigError(f"{where}: must be a table of keys, got {type(d).__name__} {d!r}")
    unknown = [k for k in d if k not in allowed]
    if unknown:
        parts = []
        for k in unknown:
            close = difflib.get_close_matches(str(k), allowed, n=1, cutoff=0.6)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            parts.append(f"{k!r}{hint}")
        prefix = f"{section}: " if section else ""
        raise ConfigError(
            f"{prefix}unknown key{'s' if len(unknown) > 1 else ''} {', '.join(parts)}; "
            f"allowed keys are {', '.join(allowed)}"
        )
    return d


def _q_equal(x: u.Quantity | None, y: u.Quantity | None) -> bool:
    if x is None or y is None:
        return x is None and y is None
    return x.unit.is_equivalent(y.unit) and bool(
        np.isclose(x.to_value(y.unit), y.value, rtol=1e-14)
    )


# --------------------------------------------------------------------------- sections
#
# A file section is the dataclass of the model it describes: its keys and their units come from
# the dataclass fields (``field(metadata={"unit": ...})``), the values are converted to
# Quantities here and validated once, by the model's own constructor.


def _unit_fields(cls: type) -> list[tuple[str, str]]:
    return [(f.name, f.metadata["unit"]) for f in dataclasses.fields(cls) if "unit" in f.metadata]


def _text_fields(cls: type) -> list[str]:
    return [f.name for f in dataclasses.fields(cls) if f.metadata.get("text")]


def _model_error(exc: RotmodError) -> ConfigError:
    """A model's ParameterError (``mask.slat_width must be ...``) in the file's key style."""
    msg = re.sub(r"^instrument\.", "", str(exc))
    return ConfigError(re.sub(r"^([A-Za-z_.\[\]0-9]+) must ", r"\1: must ", msg))


def _read_fields(d: dict[str, Any], cls: type, section: str, *, extra: tuple[str, ...] = (),
                 required: tuple[str, ...] = ()) -> dict[str, u.Quantity]:
    """Parse the unit-carrying fields of ``cls`` present in ``d`` (``required`` must be)."""
    fields = _unit_fields(cls)
    texts = _text_fields(cls)
    _check_keys(d, tuple(n for n, _ in fields) + tuple(texts) + extra, section)
    meta = {f.name: f.metadata for f in dataclasses.fields(cls)}
    out: dict[str, Any] = {}
    for name in texts:
        if name in d:
            key = f"{section}.{name}" if section else name
            if not isinstance(d[name], str):
                raise ConfigError(f"{key}: must be a string, got {d[name]!r}")
            out[name] = d[name]
    for name, unit in fields:
        key = f"{section}.{name}" if section else name
        if name not in d:
            if name in required:
                raise ConfigError(f"{key}: is required (e.g. '1 {unit}'), but it is missing")
            continue
        what = _WHAT.get(unit, f"a value in {unit}")
        if meta[name].get("list"):
            v = d[name]
            if not isinstance(v, list) or not v:
                raise ConfigError(
                    f"{key}: must be a non-empty list like ['1 {unit}', '2 {unit}'], got {v!r}"
                )
            out[name] = u.Quantity([parse_quantity(x, f"{key}[{i}]", unit, what)
                                    for i, x in enumerate(v)])
            continue
        out[name] = parse_quantity(d[name], key, unit, what, allow_inf=name == "mu")
    return out


def _write_fields(obj: Any, *, skip_none: bool = True) -> dict[str, Any]:
    out: dict[str, Any] = {}
    meta = {f.name: f for f in dataclasses.fields(type(obj))}
    for name in _text_fields(type(obj)):
        if getattr(obj, name) is not None:
            out[name] = getattr(obj, name)
    for name, unit in _unit_fields(type(obj)):
        v = getattr(obj, name)
        if v is None and skip_none:
            continue
        f = meta[name]
        if f.metadata.get("skip_default") and np.all(u.Quantity(v).value == f.default):
            continue  # an ideal-instrument value: the file stays as it was
        if f.metadata.get("list"):
            out[name] = [_fmt_q(float(x) * u.Unit(unit)) for x in v]
            continue
        # Plain numbers are in the field's unit; Quantities (angles, held in rad) convert.
        q = v.to(unit) if isinstance(v, u.Quantity) else float(v) * u.Unit(unit)
        out[name] = _fmt_q(q)
    return out


_WHAT = {
    "cm": "a length", "s": "a time", "keV": "an energy", "1/cm": "a linear attenuation "
    "coefficient", "g/cm3": "a density", "cm2/g": "a mass attenuation coefficient",
    "deg": "an angle",
}


def _material(d: Any, section: str = "material", default: str = "lead") -> Any:
    _check_keys(d, ("name", *(n for n, _ in _unit_fields(Material))), section)
    q = _read_fields({k: v for k, v in d.items() if k != "name"}, Material, section)
    if "name" not in d and default is None:
        raise ConfigError(f"{section}.name: is required (e.g. 'NaI'), but it is missing")
    try:
        return Material(d.get("name", default), **q)
    except RotmodError as exc:
        msg = str(exc)
        if msg.startswith("material."):
            raise _model_error(type(exc)(section + msg[len("material"):])) from exc
        if not isinstance(exc, MaterialError):
            raise
        raise ConfigError(f"{section}.name: {exc}") from exc


def _mask(d: Any, material: Any) -> Any:
    q = _read_fields(d, Mask, "mask", required=("slat_width", "slat_gap", "thickness", "height"))
    return Mask(material=material, **q)


def _detectors(d: Any, material: Any = None) -> Any:
    arr = _detector_layout(d)
    if "thickness" not in d:
        if material is not None:
            raise ConfigError(
                "detector_material: the [detector_material] table needs detectors.thickness "
                "(flat faces count every photon)"
            )
        return arr
    H = _quantity(d, "thickness", "detectors", "cm", "a length", strict=False)
    if material is None and H.to_value(u.cm) > 0:
        # Said of the table that is missing, not of the attribute it would fill.
        raise ConfigError(
            f"detector_material: the [detector_material] table is required with "
            f"detectors.thickness = {d['thickness']!r} (the counting probability needs the "
            "detectors' attenuation), e.g. [detector_material] name = \"NaI\", density = "
            "\"3.67 g/cm3\"")
    return arr.__class__(arr.positions, arr.diameter, H, material)


def _detector_layout(d: Any) -> Any:
    section = "detectors"
    _check_keys(d, _DETECTOR_KEYS, section)
    layout = d.get("layout", "single")
    if layout not in _LAYOUTS:
        close = difflib.get_close_matches(str(layout), _LAYOUTS, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ConfigError(
            f"{section}.layout: must be one of {', '.join(_LAYOUTS)}, got {layout!r}{hint}"
        )
    allowed = (*_PER_LAYOUT[layout], "thickness")
    extra = [k for k in d if k not in allowed]
    if extra:
        raise ConfigError(
            f"{section}: key{'s' if len(extra) > 1 else ''} {', '.join(map(repr, extra))} "
            f"not used by layout {layout!r}; that layout takes {', '.join(allowed)}"
        )
    c = _quantity(d, "diameter", section, "cm", "a length", lo=-math.inf)

    def length(name: str) -> u.Quantity | None:
        return _quantity(d, name, section, "cm", "a length", lo=-math.inf, required=False)

    if layout == "single":
        x0, y0 = length("x0"), length("y0")
        return DetectorArray.single(c, 0.0 if x0 is None else x0, 0.0 if y0 is None else y0)
    if layout == "list":
        pos = d.get("positions")
        key = f"{section}.positions"
        if not isinstance(pos, list) or not pos:
            raise ConfigError(
                f"{key}: must be a non-empty list of [x, y] pairs like "
                f"[['0 cm', '0 cm'], ['8 cm', '0 cm']], got {pos!r}"
            )
        xy = []
        for i, p in enumerate(pos):
            if not isinstance(p, list | tuple) or len(p) != 2:
                raise ConfigError(f"{key}[{i}]: must be an [x, y] pair, got {p!r}")
            xy.append([parse_quantity(v, f"{key}[{i}][{j}]", "cm", "a length").to_value(u.cm)
                       for j, v in enumerate(p)])
        xy_arr = np.array(xy)
        if len(xy_arr) > 1:
            # A built instrument's faces cannot overlap (two at one position would count the
            # same photons twice).  The model class allows it: virtual probe positions in
            # validation studies may overlap.
            gap = np.hypot(*(xy_arr[:, None, :] - xy_arr[None, :, :]).transpose(2, 0, 1))
            np.fill_diagonal(gap, np.inf)
            i, j = np.unravel_index(int(np.argmin(gap)), gap.shape)
            if gap[i, j] < c.to_value(u.cm) * (1 - 1e-12):
                raise ConfigError(
                    f"{key}: detectors {min(i, j)} and {max(i, j)} overlap (centres "
                    f"{gap[i, j]:g} cm apart, less than the diameter {_fmt_q(c)})"
                )
        return DetectorArray(xy_arr, c)
    rings = d.get("rings", 2)
    if isinstance(rings, bool) or not isinstance(rings, int):
        raise ConfigError(f"{section}.rings: must be an integer >= 0, got {rings!r}")
    return DetectorArray.hexagonal(c, rings=rings, pitch=length("pitch"))


_DETECTOR_KEYS = ("layout", "diameter", "x0", "y0", "positions", "rings", "pitch",
                  "thickness")


@dataclass(frozen=True, eq=False)
class InstrumentConfig:
    """An :class:`~rotmod.geometry.Instrument` with what a file adds: energies, name, text.

    The file's ``[mask]``, ``[material]`` and ``[detectors]`` tables are the instrument's
    dataclasses written with units (see the module notes); reading builds the
    :class:`~rotmod.geometry.Instrument` directly, so every value is validated once, by the
    model, and writing needs nothing but the instrument.

    Parameters
    ----------
    instrument : Instrument
    energies : tuple of Quantity
        Photon energies of interest (the first is the default of the CLI commands).
    name, description : str
        Free text.
    """

    instrument: Any
    energies: tuple[u.Quantity, ...] = field(default_factory=lambda: (662.0 * u.keV,))
    name: str = ""
    description: str = ""

    KEYS = (
        "name", "description", "rotation_period", "energies", "mask", "material", "detectors",
        "detector_material", "extends",
    )

    # ---------------------------------------------------------------- reading

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> InstrumentConfig:
        """Validate a parsed file and build the configuration.

        Raises
        ------
        ConfigError
            A missing section or key, an unknown key, or a value that breaks its rule.
        """
        try:
            cfg = cls._build(d)
        except ConfigError:
            raise
        except RotmodError as exc:
            # The units parser and the model classes raise ParameterError in their own
            # words; a file's reader gets them as ConfigError in the file's key style.
            raise _model_error(exc) from exc
        cfg._check_energies()
        return cfg

    @classmethod
    def _build(cls, d: dict[str, Any]) -> InstrumentConfig:
        _check_keys(d, cls.KEYS, "")
        if "extends" in d:
            # Function-local: resolving ``extends`` reads files (rotmod.io.config), and that
            # module builds on this one.
            from rotmod.io.config import resolve_extends

            d = resolve_extends(d)
        for sec in ("mask", "detectors"):
            if sec not in d:
                raise ConfigError(f"{sec}: the [{sec}] table is required, but it is missing")
        for k in ("name", "description"):
            if k in d and not isinstance(d[k], str):
                raise ConfigError(f"{k}: must be a string, got {d[k]!r}")
        energies_raw = d.get("energies", ["662 keV"])
        if isinstance(energies_raw, str):
            energies_raw = [energies_raw]
        if not isinstance(energies_raw, list) or not energies_raw:
            raise ConfigError(
                f"energies: must be a non-empty list like ['122 keV', '662 keV'], "
                f"got {energies_raw!r}"
            )
        energies = []
        for i, e in enumerate(energies_raw):
            q = parse_quantity(e, f"energies[{i}]", "keV", "an energy")
            _check_bound(q, f"energies[{i}]", "keV", lo=0.0, strict=True, original=e)
            energies.append(q)
        top = {k: d[k] for k in ("rotation_period",) if k in d}
        det_mat = (_material(d["detector_material"], "detector_material", None)
                   if "detector_material" in d else None)
        inst = Instrument(
            _mask(d["mask"], _material(d.get("material", {}))),
            _detectors(d["detectors"], det_mat), **_read_fields(top, Instrument, ""),
        )
        return cls(inst, tuple(energies), d.get("name", ""), d.get("description", ""))

    def _check_energies(self) -> None:
        m = self.instrument.mask
        if m.mu is not None or m.material.mass_attenuation is not None:
            return
        lo, hi = DATABASE_RANGE_KEV
        for i, e in enumerate(self.energies):
            v = e.to_value(u.keV)
            if not lo <= v <= hi:
                raise ConfigError(
                    f"energies[{i}]: must lie within the attenuation database's range "
                    f"{lo:g} keV to {hi:g} keV, got {_fmt_q(e)}"
                )

    @classmethod
    def read(cls, path: str | os.PathLike) -> InstrumentConfig:
        """Read and validate a TOML (or ``.yaml``/``.yml``) instrument file
        (:func:`rotmod.io.config.read_instrument_config`, the one reader).

        Raises
        ------
        ConfigError
            The file is missing, not valid TOML/YAML, or fails validation (the message starts
            with the file name).
        """
        from rotmod.io.config import read_instrument_config  # files live in io, built on this

        return read_instrument_config(path)

    # ---------------------------------------------------------------- writing

    def to_dict(self) -> dict[str, Any]:
        """The file's content: the instrument's fields as strings with units."""
        inst = self.instrument
        m, mat, det = inst.mask, inst.mask.material, inst.detectors
        out: dict[str, Any] = {}
        if self.name:
            out["name"] = self.name
        if self.description:
            out["description"] = self.description
        out.update(_write_fields(inst))
        out["energies"] = [_fmt_q(e) for e in self.energies]
        out["mask"] = _write_fields(m)
        out["material"] = {"name": mat.name, **_write_fields(mat)}
        if len(det) == 1:
            x, y = det.positions[0]
            out["detectors"] = {"layout": "single", "diameter": _fmt_q(det.diameter * u.cm),
                                "x0": _fmt_q(x * u.cm), "y0": _fmt_q(y * u.cm)}
        else:
            out["detectors"] = {
                "layout": "list", "diameter": _fmt_q(det.diameter * u.cm),
                "positions": [[_fmt_q(x * u.cm), _fmt_q(y * u.cm)] for x, y in det.positions],
            }
        if not det.is_flat:
            out["detectors"]["thickness"] = _fmt_q(det.thickness * u.cm)
            out["detector_material"] = {"name": det.material.name,
                                        **_write_fields(det.material)}
        return out

    def to_toml(self) -> str:
        """The configuration as TOML text (reads back to an equal configuration)."""
        from rotmod.io.config import dumps_toml  # files live in io, built on this module

        return dumps_toml(self.to_dict())

    def write(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write the configuration as TOML, atomically
        (:func:`rotmod.io.config.write_instrument_config`, the one writer).

        Raises
        ------
        ConfigError
            ``path`` exists and ``overwrite`` is false.
        """
        from rotmod.io.config import write_instrument_config  # files live in io (see read)

        return write_instrument_config(self, path, overwrite=overwrite)

    # ---------------------------------------------------------------- use

    def to_instrument(self) -> Instrument:
        """The :class:`~rotmod.geometry.Instrument` this file describes."""
        return self.instrument

    @property
    def energies_kev(self) -> np.ndarray:
        """Energies of interest in keV."""
        return np.array([e.to_value(u.keV) for e in self.energies])

    def replace(self, **changes: Any) -> InstrumentConfig:
        """A copy with fields replaced."""
        return dataclasses.replace(self, **changes)

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, InstrumentConfig)
            and self.instrument == other.instrument
            and len(self.energies) == len(other.energies)
            and all(_q_equal(x, y) for x, y in zip(self.energies, other.energies, strict=True))
            and self.name == other.name
            and self.description == other.description
        )

    __hash__ = None  # type: ignore[assignment]


#: The file-handling names this module offered before they moved to :mod:`rotmod.io.config`.
_MOVED_TO_IO = ("dumps_toml", "list_presets", "load_instrument", "load_instrument_config",
                "preset_path")


def __getattr__(name: str) -> Any:
    """``rotmod.config.load_instrument`` and the other file functions, from rotmod.io.config.

    Looked up on first use: rotmod.io.config builds on this module, so importing it here at
    module level would be a cycle.
    """
    if name in _MOVED_TO_IO:
        from rotmod.io import config as io_config

        warnings.warn(f"rotmod.config.{name} moved to rotmod.io (rotmod.io.{name}, or "
                      f"rotmod.io.config.{name}); the old name will be removed",
                      DeprecationWarning, stacklevel=2)
        return getattr(io_config, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
