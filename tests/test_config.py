"""Instrument description files: validation, unknown keys, presets, round trip."""

from __future__ import annotations

import copy
import tomllib

import astropy.units as u
import numpy as np
import pytest

from rotmod.config import ConfigError, InstrumentConfig
from rotmod.errors import ParameterError, RotmodError
from rotmod.io import list_presets, load_instrument, load_instrument_config

BASE = {
    "name": "t",
    "rotation_period": "30 s",
    "energies": ["122 keV", "0.662 MeV"],
    "mask": {"slat_width": "4 cm", "slat_gap": "40 mm", "thickness": "2 cm",
             "height": "1 m"},
    "material": {"name": "lead", "density": "11.34 g/cm3"},
    "detectors": {"layout": "single", "diameter": "4 cm", "x0": "1 cm", "y0": "-2 cm"},
}


def with_(path: str, value: object) -> dict:
    """A copy of BASE with the dotted ``path`` set (or removed when value is ...)."""
    d = copy.deepcopy(BASE)
    *head, last = path.split(".")
    node = d
    for k in head:
        node = node[k]
    if value is ...:
        del node[last]
    else:
        node[last] = value
    return d


def test_base_builds_instrument_in_canonical_units() -> None:
    inst = InstrumentConfig.from_dict(BASE).to_instrument()
    assert inst.mask.slat_gap == pytest.approx(4.0)
    assert inst.mask.height == pytest.approx(100.0)
    assert inst.rotation_period == 30.0
    assert np.allclose(inst.detectors.positions, [[1.0, -2.0]])


def test_round_trip_through_a_file(tmp_path) -> None:
    cfg = InstrumentConfig.from_dict(BASE)
    path = cfg.write(tmp_path / "inst.toml")
    again = InstrumentConfig.read(path)
    assert again == cfg
    assert again.to_instrument() == cfg.to_instrument()
    # Written in rotmod's units (the file is the Instrument's serialisation).
    assert tomllib.loads(path.read_text())["mask"]["slat_gap"] == "4 cm"


def test_write_refuses_existing_file(tmp_path) -> None:
    cfg = InstrumentConfig.from_dict(BASE)
    cfg.write(tmp_path / "i.toml")
    with pytest.raises(ConfigError, match="exists"):
        cfg.write(tmp_path / "i.toml")
    cfg.write(tmp_path / "i.toml", overwrite=True)


@pytest.mark.parametrize("name", ["paper", "prototype"])
def test_presets_load_and_round_trip(name: str, tmp_path) -> None:
    assert name in list_presets()
    cfg = load_instrument_config(name)
    assert InstrumentConfig.from_dict(tomllib.loads(cfg.to_toml())) == cfg
    inst = cfg.to_instrument()
    if name == "paper":
        m = inst.mask
        assert (m.slat_width, m.slat_gap, m.thickness, m.height) == (4.0, 4.0, 2.0, 100.0)
        assert m.material.density == 11.34 and len(inst.detectors) == 1
        assert np.allclose(cfg.energies_kev, [122, 662])
    else:
        assert len(inst.detectors) == 19 and inst.detectors.diameter == 3.8
        # b / L = 1.9 deg
        assert np.degrees(np.arctan(inst.mask.slat_gap / inst.mask.height)) == pytest.approx(
            1.9, abs=1e-3)


def test_yaml_file_and_path_or_preset(tmp_path) -> None:
    import yaml

    p = tmp_path / "inst.yaml"
    p.write_text(yaml.safe_dump(BASE))
    assert load_instrument(p) == InstrumentConfig.from_dict(BASE).to_instrument()
    assert load_instrument(str(p)) == load_instrument(p)


@pytest.mark.parametrize(
    ("path", "value", "match"),
    [
        # Values are validated by the model classes, in the canonical units.
        ("mask.slat_width", "-4 cm", r"mask\.slat_width: must be >= 0 cm, got -4 cm"),
        ("mask.slat_gap", "-1 cm", r"mask\.slat_gap: must be >= 0 cm, got -1 cm"),
        ("mask.thickness", "-1 mm", r"mask\.thickness: must be >= 0 cm, got -0.1 cm"),
        ("mask.height", "4 keV", r"mask\.height: must be a length .*got '4 keV'"),
        ("mask.slat_width", 4, r"mask\.slat_width: must be a length .*bare number 4"),
        ("mask.slat_width", "four cm", r"mask\.slat_width: must be a length .*'four cm'"),
        ("mask.slat_width", "4", r"mask\.slat_width: must be a length .*no unit"),
        ("mask.slat_width", "nan cm", r"mask\.slat_width: must be finite"),
        ("mask.mu", "-1 1/cm", r"mask\.mu: must be >= 0 1/cm, got -1 1/cm"),
        ("mask.height", ..., r"mask\.height: is required"),
        ("material.density", "-2 g/cm3", r"material\.density: must be > 0 g/cm3"),
        ("material.mass_attenuation", "1 cm", r"material\.mass_attenuation: must be a mass "),
        ("material.name", "unobtainium", r"material\.name: .*unobtainium"),
        ("material.name", "", r"material\.name: must be a non-empty string"),
        ("detectors.diameter", "0 cm", r"detectors\.diameter: must be > 0 cm, got 0 cm"),
        ("detectors.layout", "hexagon", r"detectors\.layout: must be one of .*'hexagonal'"),
        ("detectors.x0", "1 s", r"detectors\.x0: must be a length"),
        ("rotation_period", "0 s", r"rotation_period: must be > 0 s, got 0 s"),
        ("rotation_period", "60 cm", r"rotation_period: must be a time"),
        ("energies", [], r"energies: must be a non-empty list"),
        ("energies", ["-5 keV"], r"energies\[0\]: must be > 0 keV, got -5 keV"),
        ("energies", ["1e12 keV"], r"energies\[0\]: must lie within .* range"),
        ("name", 3, r"name: must be a string, got 3"),
        ("mask", ..., r"mask: the \[mask\] table is required"),
    ],
)
def test_every_validation_error_names_key_value_and_rule(path, value, match) -> None:
    with pytest.raises(ConfigError, match=match):
        InstrumentConfig.from_dict(with_(path, value))


def test_errors_belong_to_the_rotmod_family() -> None:
    with pytest.raises(ParameterError):
        InstrumentConfig.from_dict(with_("mask.slat_width", "-4 cm"))
    assert issubclass(ConfigError, RotmodError) and issubclass(ConfigError, ValueError)


@pytest.mark.parametrize(
    ("path", "match"),
    [
        ("mask.slat_widht", r"mask: unknown key 'slat_widht' \(did you mean 'slat_width'\?\)"),
        ("material.densty", r"material: unknown key 'densty' \(did you mean 'density'\?\)"),
        ("energy", r"unknown key 'energy' \(did you mean 'energies'\?\)"),
        ("colour", r"unknown key 'colour'; allowed keys are name, description"),
    ],
)
def test_unknown_keys_are_refused_with_a_suggestion(path, match) -> None:
    with pytest.raises(ConfigError, match=match):
        InstrumentConfig.from_dict(with_(path, "4 cm"))


def test_keys_of_another_layout_are_refused() -> None:
    d = with_("detectors.rings", 2)
    with pytest.raises(ConfigError, match=r"detectors: key 'rings' not used by layout 'single'"):
        InstrumentConfig.from_dict(d)


def test_list_and_hexagonal_layouts() -> None:
    d = with_("detectors", {"layout": "list", "diameter": "3 cm",
                            "positions": [["0 cm", "0 cm"], ["80 mm", "1 cm"]]})
    inst = InstrumentConfig.from_dict(d).to_instrument()
    assert np.allclose(inst.detectors.positions, [[0, 0], [8, 1]])
    d = with_("detectors", {"layout": "list", "diameter": "3 cm", "positions": [["0 cm"]]})
    with pytest.raises(ConfigError, match=r"detectors\.positions\[0\]: must be an \[x, y\] pair"):
        InstrumentConfig.from_dict(d)
    d = with_("detectors", {"layout": "hexagonal", "diameter": "3.8 cm", "rings": 1,
                            "pitch": "3 cm"})
    with pytest.raises(ConfigError, match=r"detectors\.pitch: must be >= detectors\.diameter"):
        InstrumentConfig.from_dict(d)
    d = with_("detectors", {"layout": "hexagonal", "diameter": "3.8 cm", "rings": -1})
    with pytest.raises(ConfigError, match=r"detectors\.rings: must be an integer >= 0, got -1"):
        InstrumentConfig.from_dict(d)


def test_bad_files_and_unknown_preset(tmp_path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("mask = [")
    with pytest.raises(ConfigError, match=r"bad\.toml.*not valid"):
        load_instrument_config(bad)
    with pytest.raises(ConfigError, match=r"'papr' is neither .*did you mean 'paper'"):
        load_instrument_config("papr")
    with pytest.raises(ConfigError, match="does not exist"):
        load_instrument_config(tmp_path / "missing.toml")
    wrong = tmp_path / "w.toml"
    from rotmod.io.config import dumps_toml

    wrong.write_text(dumps_toml(with_("mask.slat_width", "-4 cm")))
    with pytest.raises(ConfigError, match=r"w\.toml: mask\.slat_width: must be >= 0 cm"):
        load_instrument_config(wrong)


def test_units_are_converted_once_into_the_instrument() -> None:
    cfg = InstrumentConfig.from_dict(BASE)
    assert cfg.instrument.mask.slat_gap == pytest.approx(4.0)  # "40 mm"
    assert cfg.energies[1].to_value(u.keV) == pytest.approx(662.0)


def test_opaque_mask_and_hexagonal_array_round_trip(tmp_path) -> None:
    d = with_("mask.mu", "inf 1/cm")
    d["detectors"] = {"layout": "hexagonal", "diameter": "3.8 cm", "rings": 1}
    cfg = InstrumentConfig.from_dict(d)
    assert np.isposinf(cfg.instrument.mask.mu) and len(cfg.instrument.detectors) == 7
    assert InstrumentConfig.read(cfg.write(tmp_path / "o.toml")) == cfg


def test_overlapping_detectors_in_a_list_are_refused() -> None:
    d = with_("detectors", {"layout": "list", "diameter": "3 cm",
                            "positions": [["0 cm", "0 cm"], ["2 cm", "0 cm"]]})
    with pytest.raises(ConfigError, match=r"detectors\.positions: detectors 0 and 1 overlap"):
        InstrumentConfig.from_dict(d)


def test_the_file_functions_moved_to_io_warn_where_they_were() -> None:
    import rotmod.config

    with pytest.warns(DeprecationWarning, match=r"rotmod\.config\.load_instrument moved to "
                                                r"rotmod\.io"):
        old = rotmod.config.load_instrument
    assert old is load_instrument
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        rotmod.config.nonsense  # noqa: B018 - the lookup is the test
