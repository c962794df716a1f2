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
    density = "11.34 g/cm3"
    # mass_attenuation = "0.103 cm2/g"   # optional: fixed at every energy

    [detectors]
    layout = "single"        # or "list" (positions = [["0 cm", "0 cm"], ...]) or "hexagonal"
    diameter = "4 cm"
    x0 = "0 cm"
    y0 = "0 cm"
    # hexagonal: rings = 2, pitch = "3.99 cm"

Every value is checked on load; an error names the key, the value and the rule
(``mask.slat_width: must be > 0 cm, got -4 cm``) and unknown keys are refused with the
closest allowed spelling suggested.  The typed form (:class:`InstrumentConfig` and its parts)
converts to a :class:`~rotmod.geometry.Instrument` and writes back to a file that loads to an
equal configuration.

Presets ship with the package (``rotmod/presets/*.toml``): ``paper`` and ``prototype``;
:func:`load_instrument` accepts a preset name or a path.
"""

from __future__ import annotations

import difflib
import math
import os
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._atomic import write_text
from rotmod._deps import optional_import
from rotmod.errors import ParameterError, RotmodError

__all__ = [
    "ConfigError",
    "DetectorsConfig",
    "InstrumentConfig",
    "MaskConfig",
    "MaterialConfig",
    "list_presets",
    "load_instrument",
    "load_instrument_config",
    "parse_quantity",
    "preset_path",
]

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


def _fmt_q(q: u.Quantity) -> str:
    """``Quantity`` as a string that :func:`parse_quantity` reads back exactly."""
    unit = q.unit.to_string()
    value = float(q.value)
    text = f"{value:.15g}"
    if float(text) != value:
        text = repr(value)
    return f"{text} {unit}".strip() if unit else text


def parse_quantity(value: Any, key: str, unit: u.UnitBase | str, what: str) -> u.Quantity:
    """Parse ``value`` (a string such as ``"4 cm"`` or a Quantity) as a quantity of ``unit``.

    Parameters
    ----------
    value : str or Quantity
        The value read from the file.
    key : str
        Dotted key used in error messages (``"mask.slat_width"``).
    unit : str or UnitBase
        Any unit of the required physical type (``"cm"``).
    what : str
        The physical type in words (``"a length"``).

    Returns
    -------
    astropy.units.Quantity
        The value with its unit as written.

    Raises
    ------
    ConfigError
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
            raise ConfigError(
                f"{key}: must be {what} written with a unit like {example}, got {value!r}"
            ) from exc
    elif isinstance(value, bool):
        raise ConfigError(
            f"{key}: must be {what} written with a unit like {example}, got {value!r}"
        )
    elif isinstance(value, int | float):
        raise ConfigError(
            f"{key}: must be {what} written as a string with a unit like {example}, "
            f"got the bare number {value!r}"
        )
    else:
        raise ConfigError(
            f"{key}: must be {what} written with a unit like {example}, got {value!r}"
        )
    if q.isscalar is False:
        raise ConfigError(f"{key}: must be a single value, got {value!r}")
    if q.unit == u.dimensionless_unscaled and target != u.dimensionless_unscaled:
        raise ConfigError(
            f"{key}: must be {what} written with a unit like {example}, got {value!r} (no unit)"
        )
    if not q.unit.is_equivalent(target):
        raise ConfigError(
            f"{key}: must be {what} (convertible to {target.to_string()}), got {value!r}"
        )
    if not np.isfinite(q.value):
        raise ConfigError(f"{key}: must be finite, got {value!r}")
    return q


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


@dataclass(frozen=True, eq=False)
class MaterialConfig:
    """Slat material: a name (element, formula or common name), density, optional sigma.

    Parameters
    ----------
    name : str
        ``"lead"``, ``"Pb"``, ``"W"``, ``"CdZnTe"``...
    density : Quantity, optional
        g/cm3 (or any density unit); default the database value for elements.
    mass_attenuation : Quantity, optional
        A constant mass attenuation coefficient (cm2/g) used at every energy instead of the
        NIST XCOM tables.
    """

    name: str = "lead"
    density: u.Quantity | None = None
    mass_attenuation: u.Quantity | None = None

    KEYS = ("name", "density", "mass_attenuation")

    @classmethod
    def from_dict(cls, d: dict[str, Any], section: str = "material") -> MaterialConfig:
        """Validate and build from a file's table."""
        _check_keys(d, cls.KEYS, section)
        name = d.get("name", "lead")
        if not isinstance(name, str) or not name.strip():
            raise ConfigError(f"{section}.name: must be a non-empty string, got {name!r}")
        rho = _quantity(d, "density", section, "g/cm3", "a density", required=False)
        sig = _quantity(
            d, "mass_attenuation", section, "cm2/g", "a mass attenuation coefficient",
            strict=False, required=False,
        )
        cfg = cls(name, rho, sig)
        cfg.to_material(section)  # unknown material names fail here, at load
        return cfg

    def to_dict(self) -> dict[str, Any]:
        """Plain strings for a file."""
        out: dict[str, Any] = {"name": self.name}
        if self.density is not None:
            out["density"] = _fmt_q(self.density)
        if self.mass_attenuation is not None:
            out["mass_attenuation"] = _fmt_q(self.mass_attenuation)
        return out

    def to_material(self, section: str = "material") -> Any:
        """The :class:`~rotmod.materials.Material`."""
        from rotmod.materials import Material

        try:
            return Material(
                self.name,
                density=None if self.density is None else self.density.to_value("g/cm3"),
                mass_attenuation=None
                if self.mass_attenuation is None
                else self.mass_attenuation.to_value("cm2/g"),
            )
        except RotmodError as exc:
            raise ConfigError(f"{section}.name: {exc}") from exc

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, MaterialConfig)
            and self.name == other.name
            and _q_equal(self.density, other.density)
            and _q_equal(self.mass_attenuation, other.mass_attenuation)
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class MaskConfig:
    """Slat mask: ``a`` (slat_width), ``b`` (slat_gap), ``h`` (thickness), ``L`` (height).

    ``mu`` optionally fixes the linear attenuation coefficient (1/cm) at every energy.
    """

    slat_width: u.Quantity
    slat_gap: u.Quantity
    thickness: u.Quantity
    height: u.Quantity
    mu: u.Quantity | None = None

    KEYS = ("slat_width", "slat_gap", "thickness", "height", "mu")

    @classmethod
    def from_dict(cls, d: dict[str, Any], section: str = "mask") -> MaskConfig:
        """Validate and build from a file's table."""
        _check_keys(d, cls.KEYS, section)
        a = _quantity(d, "slat_width", section, "cm", "a length")
        b = _quantity(d, "slat_gap", section, "cm", "a length")
        h = _quantity(d, "thickness", section, "cm", "a length", strict=False)
        L = _quantity(d, "height", section, "cm", "a length")
        mu = _quantity(
            d, "mu", section, "1/cm", "a linear attenuation coefficient", strict=False,
            required=False,
        )
        return cls(a, b, h, L, mu)  # type: ignore[arg-type]

    def to_dict(self) -> dict[str, Any]:
        """Plain strings for a file."""
        out = {k: _fmt_q(getattr(self, k)) for k in self.KEYS[:4]}
        if self.mu is not None:
            out["mu"] = _fmt_q(self.mu)
        return out

    def __eq__(self, other: object) -> bool:
        return isinstance(other, MaskConfig) and all(
            _q_equal(getattr(self, k), getattr(other, k)) for k in self.KEYS
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class DetectorsConfig:
    """Detector faces: a ``single`` one, an explicit ``list`` or a ``hexagonal`` array.

    Parameters
    ----------
    layout : {"single", "list", "hexagonal"}
    diameter : Quantity
        ``c``, the diameter of every detector face.
    x0, y0 : Quantity
        Centre of a ``single`` detector (default on axis).
    positions : tuple of (Quantity, Quantity)
        Centres for ``list``.
    rings : int
        Hexagonal rings around the central detector (2 gives 19 detectors).
    pitch : Quantity, optional
        Centre-to-centre distance of a hexagonal array (default 1.05 diameter).
    """

    layout: str
    diameter: u.Quantity
    x0: u.Quantity = field(default_factory=lambda: 0.0 * u.cm)
    y0: u.Quantity = field(default_factory=lambda: 0.0 * u.cm)
    positions: tuple[tuple[u.Quantity, u.Quantity], ...] = ()
    rings: int = 2
    pitch: u.Quantity | None = None

    KEYS = ("layout", "diameter", "x0", "y0", "positions", "rings", "pitch")

    @classmethod
    def from_dict(cls, d: dict[str, Any], section: str = "detectors") -> DetectorsConfig:
        """Validate and build from a file's table."""
        _check_keys(d, cls.KEYS, section)
        layout = d.get("layout", "single")
        if layout not in _LAYOUTS:
            close = difflib.get_close_matches(str(layout), _LAYOUTS, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ConfigError(
                f"{section}.layout: must be one of {', '.join(_LAYOUTS)}, got {layout!r}{hint}"
            )
        allowed = _PER_LAYOUT[layout]
        extra = [k for k in d if k not in allowed]
        if extra:
            raise ConfigError(
                f"{section}: key{'s' if len(extra) > 1 else ''} {', '.join(map(repr, extra))} "
                f"not used by layout {layout!r}; that layout takes {', '.join(allowed)}"
            )
        c = _quantity(d, "diameter", section, "cm", "a length")
        if layout == "single":
            x0 = _quantity(d, "x0", section, "cm", "a length", lo=-math.inf, required=False)
            y0 = _quantity(d, "y0", section, "cm", "a length", lo=-math.inf, required=False)
            return cls(layout, c, 0.0 * u.cm if x0 is None else x0,  # type: ignore[arg-type]
                       0.0 * u.cm if y0 is None else y0)
        if layout == "list":
            pos = d.get("positions")
            key = f"{section}.positions"
            if not isinstance(pos, list) or not pos:
                raise ConfigError(
                    f"{key}: must be a non-empty list of [x, y] pairs like "
                    f"[['0 cm', '0 cm'], ['8 cm', '0 cm']], got {pos!r}"
                )
            out = []
            for i, p in enumerate(pos):
                if not isinstance(p, list | tuple) or len(p) != 2:
                    raise ConfigError(f"{key}[{i}]: must be an [x, y] pair, got {p!r}")
                out.append(tuple(
                    parse_quantity(v, f"{key}[{i}][{j}]", "cm", "a length")
                    for j, v in enumerate(p)
                ))
            return cls(layout, c, positions=tuple(out))  # type: ignore[arg-type]
        rings = d.get("rings", 2)
        if isinstance(rings, bool) or not isinstance(rings, int) or rings < 0:
            raise ConfigError(f"{section}.rings: must be an integer >= 0, got {rings!r}")
        pitch = _quantity(d, "pitch", section, "cm", "a length", required=False)
        if pitch is not None and pitch < c:
            raise ConfigError(
                f"{section}.pitch: must be >= {section}.diameter ({_fmt_q(c)}) so faces do "
                f"not overlap, got {d['pitch']}"
            )
        return cls(layout, c, rings=rings, pitch=pitch)  # type: ignore[arg-type]

    def to_dict(self) -> dict[str, Any]:
        """Plain values for a file (only the keys of the layout)."""
        out: dict[str, Any] = {"layout": self.layout, "diameter": _fmt_q(self.diameter)}
        if self.layout == "single":
            out["x0"] = _fmt_q(self.x0)
            out["y0"] = _fmt_q(self.y0)
        elif self.layout == "list":
            out["positions"] = [[_fmt_q(x), _fmt_q(y)] for x, y in self.positions]
        else:
            out["rings"] = self.rings
            if self.pitch is not None:
                out["pitch"] = _fmt_q(self.pitch)
        return out

    def to_detectors(self) -> Any:
        """The :class:`~rotmod.geometry.DetectorArray`."""
        from rotmod.geometry import DetectorArray

        c = self.diameter.to_value(u.cm)
        if self.layout == "single":
            return DetectorArray.single(c, self.x0.to_value(u.cm), self.y0.to_value(u.cm))
        if self.layout == "list":
            pos = np.array([[x.to_value(u.cm), y.to_value(u.cm)] for x, y in self.positions])
            return DetectorArray(pos, c)
        pitch = None if self.pitch is None else self.pitch.to_value(u.cm)
        return DetectorArray.hexagonal(c, rings=self.rings, pitch=pitch)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, DetectorsConfig):
            return False
        return self.to_dict() == other.to_dict() or (
            self.layout == other.layout
            and self.rings == other.rings
            and _q_equal(self.diameter, other.diameter)
            and _q_equal(self.x0, other.x0)
            and _q_equal(self.y0, other.y0)
            and _q_equal(self.pitch, other.pitch)
            and len(self.positions) == len(other.positions)
            and all(
                _q_equal(p, q)
                for pp, qq in zip(self.positions, other.positions, strict=True)
                for p, q in zip(pp, qq, strict=True)
            )
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class InstrumentConfig:
    """A complete instrument description (see the module notes for the file layout).

    Parameters
    ----------
    mask : MaskConfig
    material : MaterialConfig
    detectors : DetectorsConfig
    rotation_period : Quantity
        One full mask turn (time).
    energies : tuple of Quantity
        Photon energies of interest (the first is the default of the CLI commands).
    name, description : str
        Free text.
    """

    mask: MaskConfig
    material: MaterialConfig
    detectors: DetectorsConfig
    rotation_period: u.Quantity = field(default_factory=lambda: 60.0 * u.s)
    energies: tuple[u.Quantity, ...] = field(default_factory=lambda: (662.0 * u.keV,))
    name: str = ""
    description: str = ""

    KEYS = (
        "name", "description", "rotation_period", "energies", "mask", "material", "detectors",
    )

    # ---------------------------------------------------------------- reading

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> InstrumentConfig:
        """Validate a parsed file and build the typed configuration.

        Raises
        ------
        ConfigError
            A missing section or key, an unknown key, or a value that breaks its rule.
        """
        _check_keys(d, cls.KEYS, "")
        for sec in ("mask", "detectors"):
            if sec not in d:
                raise ConfigError(f"{sec}: the [{sec}] table is required, but it is missing")
        for k in ("name", "description"):
            if k in d and not isinstance(d[k], str):
                raise ConfigError(f"{k}: must be a string, got {d[k]!r}")
        mask = MaskConfig.from_dict(d["mask"])
        material = MaterialConfig.from_dict(d.get("material", {}))
        det = DetectorsConfig.from_dict(d["detectors"])
        period = _quantity(d, "rotation_period", "", "s", "a time", required=False)
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
        cfg = cls(
            mask, material, det, 60.0 * u.s if period is None else period, tuple(energies),
            d.get("name", ""), d.get("description", ""),
        )
        cfg._check_energies()
        cfg.to_instrument()  # cross-checks of the geometry classes, reported as ConfigError
        return cfg

    def _check_energies(self) -> None:
        if self.mask.mu is not None or self.material.mass_attenuation is not None:
            return
        from rotmod.materials import DATABASE_RANGE_KEV

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
        """Read and validate a TOML (or ``.yaml``/``.yml``) instrument file.

        Raises
        ------
        ConfigError
            The file is missing, not valid TOML/YAML, or fails validation (the message starts
            with the file name).
        """
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(
                f"instrument file {str(p)!r}: cannot be read ({exc.strerror})"
            ) from exc
        try:
            if p.suffix.lower() in (".yaml", ".yml"):
                yaml = optional_import("yaml", "yaml", "YAML instrument files")
                data = yaml.safe_load(text) or {}
            else:
                data = tomllib.loads(text)
        except Exception as exc:
            raise ConfigError(f"instrument file {str(p)!r}: not valid {p.suffix[1:] or 'TOML'} "
                              f"({exc})") from exc
        try:
            return cls.from_dict(data)
        except ConfigError as exc:
            raise ConfigError(f"{p.name}: {exc}") from exc

    # ---------------------------------------------------------------- writing

    def to_dict(self) -> dict[str, Any]:
        """Plain strings, numbers and tables (the file's content)."""
        out: dict[str, Any] = {}
        if self.name:
            out["name"] = self.name
        if self.description:
            out["description"] = self.description
        out["rotation_period"] = _fmt_q(self.rotation_period)
        out["energies"] = [_fmt_q(e) for e in self.energies]
        out["mask"] = self.mask.to_dict()
        out["material"] = self.material.to_dict()
        out["detectors"] = self.detectors.to_dict()
        return out

    def to_toml(self) -> str:
        """The configuration as TOML text (reads back to an equal configuration)."""
        return dumps_toml(self.to_dict())

    def write(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write the configuration as TOML, atomically.

        Raises
        ------
        ConfigError
            ``path`` exists and ``overwrite`` is false.
        """
        p = Path(path)
        if p.exists() and not overwrite:
            raise ConfigError(f"output {str(p)!r}: exists; pass overwrite=True to replace it")
        write_text(p, self.to_toml())
        return p

    # ---------------------------------------------------------------- use

    def to_instrument(self) -> Any:
        """The :class:`~rotmod.geometry.Instrument` this file describes."""
        from rotmod.geometry import Instrument, Mask

        m = self.mask
        try:
            mask = Mask(
                m.slat_width.to_value(u.cm), m.slat_gap.to_value(u.cm),
                m.thickness.to_value(u.cm), m.height.to_value(u.cm),
                self.material.to_material(),
                None if m.mu is None else m.mu.to_value(1 / u.cm),
            )
            return Instrument(mask, self.detectors.to_detectors(),
                              self.rotation_period.to_value(u.s))
        except ConfigError:
            raise
        except RotmodError as exc:
            raise ConfigError(str(exc)) from exc

    @property
    def energies_kev(self) -> np.ndarray:
        """Energies of interest in keV."""
        return np.array([e.to_value(u.keV) for e in self.energies])

    def replace(self, **changes: Any) -> InstrumentConfig:
        """A copy with top-level fields replaced (sections are replaced whole)."""
        from dataclasses import replace

        return replace(self, **changes)

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, InstrumentConfig)
            and self.mask == other.mask
            and self.material == other.material
            and self.detectors == other.detectors
            and _q_equal(self.rotation_period, other.rotation_period)
            and len(self.energies) == len(other.energies)
            and all(_q_equal(x, y) for x, y in zip(self.energies, other.energies, strict=True))
            and self.name == other.name
            and self.description == other.description
        )

    __hash__ = None  # type: ignore[assignment]


# --------------------------------------------------------------------------- presets / loading


def list_presets() -> list[str]:
    """Names of the instrument presets shipped with the package."""
    root = resources.files("rotmod") / "presets"
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".toml"))


def preset_path(name: str) -> Path:
    """Path of the preset ``name``.

    Raises
    ------
    ConfigError
        Unknown preset (the message lists them and suggests the closest).
    """
    names = list_presets()
    if name not in names:
        close = difflib.get_close_matches(name, names, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ConfigError(
            f"instrument: {name!r} is neither an existing file nor a preset{hint}; presets are "
            f"{', '.join(names)}"
        )
    return Path(str(resources.files("rotmod") / "presets" / f"{name}.toml"))


def load_instrument_config(source: str | os.PathLike | InstrumentConfig) -> InstrumentConfig:
    """Load an instrument description from a file path or a preset name.

    Parameters
    ----------
    source : str, path-like or InstrumentConfig
        A TOML/YAML file, or the name of a preset (:func:`list_presets`).

    Returns
    -------
    InstrumentConfig
    """
    if isinstance(source, InstrumentConfig):
        return source
    p = Path(source)
    if p.is_file():
        return InstrumentConfig.read(p)
    if isinstance(source, str) and os.sep not in source and not p.suffix:
        return InstrumentConfig.read(preset_path(source))
    raise ConfigError(
        f"instrument: file {str(source)!r} does not exist (presets are "
        f"{', '.join(list_presets())})"
    )


def load_instrument(source: str | os.PathLike | InstrumentConfig) -> Any:
    """The :class:`~rotmod.geometry.Instrument` of a file path or preset name."""
    return load_instrument_config(source).to_instrument()


# --------------------------------------------------------------------------- small TOML writer


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v) or math.isinf(v):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        return repr(v)
    if isinstance(v, str):
        esc = v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
        return f'"{esc}"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dumps_toml(d: dict[str, Any]) -> str:
    """TOML text of a dict of scalars, lists and one level of tables."""
    lines: list[str] = []
    tables = []
    for k, v in d.items():
        if isinstance(v, dict):
            tables.append((k, v))
        else:
            lines.append(f"{k} = {_toml_value(v)}")
    for k, v in tables:
        lines.append("")
        lines.append(f"[{k}]")
        for kk, vv in v.items():
            if isinstance(vv, dict):
                raise TypeError("nested tables deeper than one level are not supported")
            lines.append(f"{kk} = {_toml_value(vv)}")
    return "\n".join(lines) + "\n"

