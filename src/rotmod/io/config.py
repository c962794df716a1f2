"""Instrument files: TOML (written with tomli-w, read with the stdlib's tomllib) and YAML.

The schema (what the keys mean, their units and rules) is :mod:`rotmod.config`'s; this
module only turns files into the mappings the schema validates and back: reading a file,
resolving ``extends = "<preset or file>"``, finding the presets shipped with the package and
writing a configuration atomically under the one overwrite policy.
"""

from __future__ import annotations

import difflib
import os
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import tomli_w

from rotmod._deps import optional_import
from rotmod.config import ConfigError, InstrumentConfig
from rotmod.errors import ParameterError
from rotmod.geometry import Instrument
from rotmod.io.atomic import check_overwrite, write_text

__all__ = [
    "dumps_toml",
    "list_presets",
    "load_instrument",
    "load_instrument_config",
    "preset_path",
    "read_instrument_config",
    "read_mapping",
    "resolve_extends",
    "write_instrument_config",
]

#: Extensions of YAML files (anything else is read as TOML).
YAML_SUFFIXES = (".yaml", ".yml")


def dumps_toml(d: dict[str, Any]) -> str:
    """TOML text of a mapping (the inverse of :func:`tomllib.loads`)."""
    return tomli_w.dumps(d)


def read_mapping(path: str | os.PathLike) -> dict[str, Any]:
    """The raw content of a TOML (or ``.yaml``/``.yml``) file.

    Raises
    ------
    ConfigError
        The file cannot be read, is not text, or is not valid TOML/YAML.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(
            f"instrument file {str(path)!r}: cannot be read ({exc.strerror})"
        ) from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"instrument file {str(path)!r}: is not a text file (TOML or YAML expected)"
        ) from exc
    try:
        if path.suffix.lower() in YAML_SUFFIXES:
            yaml = optional_import("yaml", "yaml", "YAML instrument files")
            return yaml.safe_load(text) or {}
        return tomllib.loads(text)
    except Exception as exc:
        raise ConfigError(f"instrument file {str(path)!r}: not valid "
                          f"{path.suffix[1:] or 'TOML'} ({exc})") from exc


def resolve_extends(d: dict[str, Any], depth: int = 0) -> dict[str, Any]:
    """Resolve ``extends = "<preset or file>"``: the base's content, with every key ``d``
    gives replacing the base's (tables key by key; a new ``[detectors]`` layout replaces the
    base's layout keys)."""
    if "extends" not in d:
        return d
    src = d["extends"]
    if not isinstance(src, str):
        raise ConfigError(f"extends: must be a preset name or a file path, got {src!r}")
    if depth > 8:
        raise ConfigError(f"extends: more than 8 levels of 'extends' (at {src!r})")
    p = Path(src)
    path = p if p.is_file() else preset_path(src) if os.sep not in src and not p.suffix else p
    if not path.is_file():
        raise ConfigError(f"extends: {src!r} is neither a preset nor an existing file")
    base = resolve_extends(read_mapping(path), depth + 1)
    out = {k: v for k, v in base.items() if k not in ("name", "description")}
    for k, v in d.items():
        if k == "extends":
            continue
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            merged = dict(out[k])
            if k == "detectors" and "layout" in v:
                merged = {}  # a new layout brings its own keys
            merged.update(v)
            out[k] = merged
        else:
            out[k] = v
    return out


def read_instrument_config(path: str | os.PathLike) -> InstrumentConfig:
    """Read and validate a TOML (or ``.yaml``/``.yml``) instrument file.

    Raises
    ------
    ConfigError
        The file is missing, not valid TOML/YAML, or fails validation (the message starts
        with the file name).
    """
    p = Path(path)
    data = read_mapping(p)
    try:
        return InstrumentConfig.from_dict(data)
    except ConfigError as exc:
        raise ConfigError(f"{p.name}: {exc}") from exc


def write_instrument_config(cfg: InstrumentConfig, path: str | os.PathLike, *,
                            overwrite: bool = False) -> Path:
    """Write ``cfg`` as TOML, atomically.

    Raises
    ------
    ConfigError
        ``path`` exists and ``overwrite`` is false.
    """
    try:
        p = check_overwrite(path, overwrite)
    except ParameterError as exc:
        # The one policy and message; the type stays the config's own (a ParameterError).
        raise ConfigError(str(exc)) from None
    return write_text(p, cfg.to_toml())


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
        return read_instrument_config(p)
    if p.is_dir():
        raise ConfigError(f"instrument: {str(source)!r} is a folder; give an instrument file "
                          f"(TOML or YAML) or a preset ({', '.join(list_presets())})")
    if isinstance(source, str) and os.sep not in source and not p.suffix:
        return read_instrument_config(preset_path(source))
    raise ConfigError(
        f"instrument: file {str(source)!r} does not exist (presets are "
        f"{', '.join(list_presets())})"
    )


def load_instrument(source: str | os.PathLike | InstrumentConfig) -> Instrument:
    """The :class:`~rotmod.geometry.Instrument` of a file path or preset name."""
    return load_instrument_config(source).instrument
