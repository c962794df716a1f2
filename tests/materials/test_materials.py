"""Attenuation data (NIST XCOM, shipped as package data from fisx): values, range and errors."""

from __future__ import annotations

import importlib.resources
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from rotmod.errors import MaterialError, ParameterError
from rotmod.geometry import Mask
from rotmod.materials import (
    DATABASE_RANGE_KEV,
    PARTIAL_PROCESSES,
    Material,
    database_provenance,
    mass_attenuation,
    partial_attenuation,
)
from rotmod.materials._formula import atom_counts

# NIST XCOM total attenuation with coherent scattering (cm2/g), from the XCOM web tables.
# fisx interpolates the same tables log-log, so agreement to 1% is expected away from
# absorption edges (the 122 keV value 3.37 is quoted to 3 digits: 0.5%).
XCOM = [
    ("Pb", 122.0, 3.37, 0.01),
    ("Pb", 662.0, 0.110, 0.01),
    ("Pb", 1000.0, 0.0710, 0.01),
    ("Pb", 3000.0, 0.0423, 0.01),
    ("W", 1000.0, 0.06618, 0.01),
    ("W", 3000.0, 0.04075, 0.01),
    ("Fe", 1000.0, 0.05995, 0.01),
    ("Fe", 3000.0, 0.03621, 0.01),
    ("Cu", 1000.0, 0.05901, 0.01),
    ("Cu", 3000.0, 0.03599, 0.01),
]


@pytest.mark.parametrize(("element", "energy", "value", "rtol"), XCOM)
def test_xcom_values(element, energy, value, rtol):
    assert mass_attenuation(element, energy) == pytest.approx(value, rel=rtol)


@pytest.mark.parametrize("element", ["Pb", "W", "Ta", "Sn", "Cu", "Fe"])
def test_elements_cover_20kev_to_3mev(element):
    e = np.geomspace(20.0, 3000.0, 80)
    sig = mass_attenuation(element, e)
    assert sig.shape == e.shape
    assert np.all(np.isfinite(sig) & (sig > 0))
    # No silent constant above 1 MeV (a failure mode of some packages): sigma keeps falling
    # through the Compton region up to 3 MeV, including across the pair threshold.
    hi = sig[e >= 800.0]
    assert np.all(np.diff(hi) < 0)
    assert Material(element).density > 0


@pytest.mark.parametrize("energy", [1022.5, 1050.0, 1100.0, 1200.0])
def test_pair_threshold_is_smooth(energy):
    # fisx's own interpolator gives Pb 1.05 cm2/g at 1022.5 keV (log-log from the zero pair
    # cross-section at threshold).  XCOM Pb: 0.06962 at 1022 keV, 0.05875 at 1250 keV, and
    # sigma is monotonic in between, so any value outside that bracket is an artefact.
    assert 0.05875 <= mass_attenuation("Pb", energy) <= 0.06963


def test_xcom_table_values_reproduced():
    # At tabulated energies the interpolation must return XCOM's totals (Pb rows of
    # fisx_data/XCOM_CrossSections.dat), to their 7 printed digits.
    e = [100.0, 600.0, 1000.0, 1250.0, 3000.0]
    xcom = [5.549085, 0.1247535, 0.0710187, 0.05875163, 0.04234072]
    assert mass_attenuation("Pb", e) == pytest.approx(xcom, rel=1e-6)
    # Across the Pb K edge (88.004 keV) the value jumps by the table's factor 7.684/1.910.
    below, above = mass_attenuation("Pb", [88.0, 88.01])
    assert above / below == pytest.approx(7.683764 / 1.909864, rel=2e-3)


def test_tin_density_is_metallic():
    # fisx's default (5.31) is grey alpha-tin; slats are white tin.
    assert Material("Sn").density == pytest.approx(7.31)


def test_names_and_compounds():
    assert mass_attenuation("lead", 662.0) == mass_attenuation("Pb", 662.0)
    czt = Material("CdZnTe", density=5.8)
    mu = czt.linear_attenuation(662.0)
    assert 0.3 < mu < 0.6  # sigma ~ 0.075 cm2/g times 5.8 g/cm3
    # Mixture rule: a compound lies between its constituents' values.
    parts = [mass_attenuation(x, 662.0) for x in ("Cd", "Zn", "Te")]
    assert min(parts) <= mass_attenuation("CdZnTe", 662.0) <= max(parts)
    with pytest.raises(MaterialError, match="no default density"):
        Material("CdZnTe")


def test_fixed_sigma_overrides_database():
    m = Material("Pb", density=11.34, mass_attenuation=0.103)
    assert m.linear_attenuation(122.0) == pytest.approx(0.103 * 11.34)
    assert Mask(4, 4, 2, 100, m).linear_attenuation() == pytest.approx(1.16802)


@pytest.mark.parametrize(
    "mask",
    [Mask(4, 4, 2, 100), Mask(4, 4, 2, 100, mu=3.5),
     Mask(4, 4, 2, 100, Material("Pb", density=11.34, mass_attenuation=0.103))],
    ids=["database", "fixed mu", "fixed sigma"],
)
def test_attenuation_of_many_energies_is_each_energy_s(mask):
    # The vectorised call (the Monte Carlo's one per source) against the scalar one, value by
    # value: the same database interpolation, so equal to the last bit.
    energies = np.array([30.0, 122.0, 662.0, 662.0, 4000.0])
    many = mask.linear_attenuation(energies)
    assert isinstance(many, np.ndarray) and many.shape == energies.shape
    assert many.tolist() == [mask.linear_attenuation(e) for e in energies]
    assert isinstance(mask.linear_attenuation(662.0), float)
    # A bad energy is refused even where the coefficient does not depend on it.
    with pytest.raises(ParameterError, match="energy"):
        mask.linear_attenuation(np.array([662.0, -1.0]))


@pytest.mark.parametrize(
    ("call", "exc", "match"),
    [
        (lambda: Material("Unobtainium"), MaterialError, "Unobtainium"),
        (lambda: mass_attenuation("Xx", 100.0), MaterialError, "'Xx' is not an element"),
        (lambda: mass_attenuation("Pb", 0.5), MaterialError, "range 1 keV to 1e.08 keV"),
        (lambda: mass_attenuation("Pb", 2e8), MaterialError, "got 2e.08 keV"),
        (lambda: mass_attenuation("Pb", -1.0), ParameterError, "energy must be > 0"),
        (lambda: mass_attenuation("Pb", np.nan), ParameterError, "energy must be finite"),
        (lambda: Material("Pb", density=-1.0), ParameterError, "material.density must be > 0"),
        (lambda: Material(""), MaterialError, "material.name must be a non-empty string"),
        (lambda: Material("Pb", mass_attenuation=-0.1), ParameterError,
         "material.mass_attenuation must be >= 0"),
    ],
)
def test_bad_material_inputs(call, exc, match):
    with pytest.raises(exc, match=match):
        call()


def test_database_range_is_documented():
    assert DATABASE_RANGE_KEV == (1.0, 1.0e8)
    mass_attenuation("Pb", [1.0, 1.0e8])  # both ends accepted


# Coefficients rotmod computed when it read fisx at run time (fisx 1.3.2, rotmod before the
# tables became package data), printed with repr: the shipped data, the formula parser and the
# mixture rule must reproduce them to the bit.  Energies: L-shell region, just above the Pb K
# edge, 662 keV, just above the pair threshold, 100 MeV.
_PINNED_E = [30.0, 88.01, 662.0, 1022.5, 1e5]
PINNED = {
    "PbWO4": [23.040916453870324, 5.996222336368318, 0.10052140700976434,
              0.06678838776043268, 0.08045410032095512],
    "Bi4Ge3O12": [23.628435538020664, 1.4911111177333547, 0.09980632096966076,
                  0.06701958234365692, 0.07453720851361394],
    "CdZnTe": [19.733338681358262, 1.9801144471861047, 0.07454829181077635,
               0.05710063200406523, 0.06303965531383418],
    "Cd0.9Zn0.1Te": [20.79464263226338, 2.3019616414552386, 0.07484455354836822,
                     0.056674892845574816, 0.06658889590295461],
    "Ca(OH)2": [2.3794658893185057, 0.2462008762657321, 0.07964057389209331,
                0.06479547447752175, 0.02815368494537525],
    "NaI": [7.35773874531543, 2.328323874920924, 0.07661875854482786, 0.05799064076632435,
            0.06296917743813497],
    "CsI": [9.04538527191902, 2.84960242072259, 0.07753456549334281, 0.057643054978757026,
            0.07116227242755521],
    "Mg(NO3)2": [0.4550248982849746, 0.1646475751405145, 0.07710746250057485,
                 0.0628888388999814, 0.018651674336716016],
}


@pytest.mark.parametrize("formula", sorted(PINNED))
def test_coefficients_identical_to_the_fisx_based_ones(formula):
    assert np.array_equal(mass_attenuation(formula, _PINNED_E), PINNED[formula])


def test_default_densities_and_lead_mu_unchanged():
    assert [Material(x).density for x in ("Pb", "W", "Sn")] == [11.34, 19.3, 7.31]
    assert Material("lead").linear_attenuation(662.0) == 1.249051385139087


@pytest.mark.parametrize(
    ("formula", "counts"),
    [
        ("Pb", {"Pb": 1.0}),
        ("Bi4Ge3O12", {"Bi": 4.0, "Ge": 3.0, "O": 12.0}),
        ("Cd0.9Zn0.1Te", {"Cd": 0.9, "Zn": 0.1, "Te": 1.0}),
        ("Ca(OH)2", {"Ca": 1.0, "O": 2.0, "H": 2.0}),
        ("Fe2(SO4)3", {"Fe": 2.0, "S": 3.0, "O": 12.0}),
        ("CH3CH2OH", {"C": 2.0, "H": 6.0, "O": 1.0}),
        ("((CH2)2O)3", {"C": 6.0, "H": 12.0, "O": 3.0}),
        ("Pb.5", {"Pb": 0.5}),
        ("PB", {"P": 1.0, "B": 1.0}),  # symbols are case-sensitive: phosphorus boride
    ],
)
def test_formula_atom_counts(formula, counts):
    assert atom_counts(formula) == counts


@pytest.mark.parametrize(
    ("formula", "match"),
    [
        ("Pb(", r"'\(' without a matching '\)'"),
        ("Pb)2", r"'\)' without a matching '\('"),
        ("Pb()", r"empty parentheses"),
        ("2Pb", "count '2' follows no element or group"),
        ("Pb0", "count '0' must be > 0"),
        ("Pb-1", "unexpected character '-' at position 2"),
        ("Pb W", "unexpected character ' ' at position 2"),
        ("pb", "unexpected character 'p' at position 0"),
        ("", "empty formula"),
    ],
)
def test_formula_errors_say_what_is_wrong(formula, match):
    with pytest.raises(MaterialError, match=match):
        atom_counts(formula)


@pytest.mark.parametrize(
    ("name", "match"),
    [
        ("PbXx4", r"'PbXx4' is not an element.*unknown element symbol 'Xx'"),
        # Mendelevium is an element, but XCOM stops at fermium (Z = 100).
        ("Md", r"unknown element symbol 'Md'; the database covers H to Fm"),
        ("Pb(WO4", r"'Pb\(WO4' is not an element.*without a matching"),
    ],
)
def test_unknown_symbols_and_bad_formulas_are_named(name, match):
    with pytest.raises(MaterialError, match=match):
        mass_attenuation(name, 100.0)
    with pytest.raises(MaterialError, match=match):
        Material(name, density=1.0)
    with pytest.raises(MaterialError, match=match):  # not "give a density"
        Material(name)


def _shipped() -> dict[str, np.ndarray]:
    with importlib.resources.files("rotmod.materials").joinpath("xcom.npz").open("rb") as f:
        with np.load(f, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}


def test_shipped_data_and_provenance():
    data = _shipped()
    meta = json.loads(str(data["provenance"]))
    assert "NIST XCOM" in meta["source"]
    assert meta["fisx_version"] == "1.3.2"
    assert meta["script"] == "scripts/extract_xcom.py"
    assert database_provenance() == meta
    assert list(data["z"]) == list(range(1, 101))
    assert data["symbol"][0] == "H" and data["symbol"][81] == "Pb" and data["symbol"][-1] == "Fm"
    table, offset = data["table"], data["offset"]
    assert table.shape == (offset[-1], 5) and table.dtype == np.float64
    for k in range(len(offset) - 1):
        e = table[offset[k]:offset[k + 1], 0]
        # increasing energy, a repeated energy being an absorption edge; 1 keV-100 GeV covered
        assert np.all(np.diff(e) >= 0) and e[0] <= 1.0 and e[-1] >= 1.0e8
    assert np.all(table[:, 1:] >= 0)


def test_shipped_data_is_what_the_script_extracts():
    # Regenerating the file from the installed fisx (when there is one) must give it back.
    pytest.importorskip("fisx")
    path = Path(__file__).resolve().parents[2] / "scripts" / "extract_xcom.py"
    spec = importlib.util.spec_from_file_location("extract_xcom", path)
    assert spec is not None and spec.loader is not None
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    fresh, shipped = script.extract(), _shipped()
    assert sorted(fresh) == sorted(shipped)
    for key in fresh:
        if key == "provenance":
            a, b = json.loads(str(fresh[key])), json.loads(str(shipped[key]))
            assert {**a, "created": None} == {**b, "created": None}
        else:
            assert fresh[key].dtype == shipped[key].dtype
            assert np.array_equal(fresh[key], shipped[key]), key


def test_partials_sum_to_the_total_and_follow_known_physics() -> None:
    """The partial cross-sections add up to the total; in NaI the photoelectric effect
    dominates at 50 keV, Compton scattering at 1 MeV, and pair production is 0 below its
    1022 keV threshold and the largest process of lead at 100 MeV (XCOM's well-known
    crossovers)."""
    e = np.geomspace(5.0, 1e5, 200)
    parts = partial_attenuation("NaI", e)
    assert parts.shape == (200, len(PARTIAL_PROCESSES))
    np.testing.assert_allclose(parts.sum(-1), mass_attenuation("NaI", e), rtol=1e-13)
    assert np.argmax(partial_attenuation("NaI", 50.0)) == 2
    assert np.argmax(partial_attenuation("NaI", 1000.0)) == 1
    assert np.all(partial_attenuation("NaI", [100.0, 1021.0])[:, 3] == 0.0)
    assert np.argmax(partial_attenuation("Pb", 1e5)) == 3


def test_mixture_by_mass_fraction() -> None:
    """A mixture ``{symbol: mass fraction}`` is the mass-weighted sum (normalised), so water
    given as fractions equals the formula H2O."""
    h, o = 2 * 1.00794, 15.9994
    water = {"H": h / (h + o), "O": o / (h + o)}
    e = np.array([30.0, 662.0, 5000.0])
    np.testing.assert_allclose(mass_attenuation(water, e), mass_attenuation("H2O", e), rtol=1e-5)
    # Unnormalised fractions are normalised.
    np.testing.assert_allclose(mass_attenuation({"N": 3, "O": 1}, e),
                               0.75 * mass_attenuation("N", e) + 0.25 * mass_attenuation("O", e))
    with pytest.raises(MaterialError, match="mixture"):
        mass_attenuation({"Xx": 1.0}, e)
    with pytest.raises(MaterialError, match="not all be 0"):
        mass_attenuation({"N": 0.0}, e)
