"""The seed paper's validation scenarios, and every profile model checked against the MC.

Scenarios (the registry :data:`SCENARIOS`) reproduce the paper's Sec. 4 set-ups (lead, rho = 11.34
g/cm3, sigma = 0.103 cm2/g at 662 keV, L = 100 cm) where the paper leaves the detector
position, azimuth and (for Figs. 5-7) thickness and zenith open, the values here are our
choice and are stated per scenario.  Each scenario has an on-axis and an off-axis detector
and two source azimuths.  Four further scenarios lie outside the advanced model's validity
(``a < h tan theta``, ``b < h tan theta``, rays crossing two slats).

:func:`run_scenario` simulates the Monte Carlo and evaluates every compared model
(:data:`rotmod.paper.selection.VALIDATION_MODELS`) that applies (a model raising
:class:`~rotmod.errors.ModelValidityError` is skipped and the reason recorded), and returns
chi-square per model.  The chi-square uses each model's own
binomial variance ``P (1 - P) / N``, with ``P`` clipped to ``[1/(2N), 1 - 1/(2N)]`` so a
cell that a model calls impossible (``P = 0``) but the MC populates counts heavily
instead of infinitely.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import astropy.units as u
import numpy as np

from rotmod._validate import as_int
from rotmod.errors import ModelValidityError, ParameterError
from rotmod.geometry import DetectorArray, Instrument, Mask
from rotmod.materials import PAPER_SIGMA_662, Material
from rotmod.montecarlo import MCProfiles, simulate_profiles
from rotmod.paper.selection import REFERENCE_MODEL, VALIDATION_MODELS
from rotmod.plotting.profiles import plot_profiles
from rotmod.profiles import DEFAULT_COMPARISON, MODELS, get_model
from rotmod.registry import Registry

__all__ = [
    "SCENARIOS",
    "Scenario",
    "ScenarioResult",
    "chi_square",
    "get_scenario",
    "plot_scenario",
    "run_scenario",
]

@dataclass(frozen=True)
class Scenario:
    """One validation set-up.

    Attributes
    ----------
    name : str
        Short identifier (used in file names).
    title : str
        One-line description.
    a, b, c, h : float
        Slat width, gap, detector diameter and slat thickness (cm).
    theta_deg : float
        Source zenith (deg).
    phi_deg : tuple of float
        Source azimuths (deg), one source each.
    detectors : tuple of (float, float)
        Detector centres (cm): the first on axis, the second off axis.
    L, sigma : float
        Mask height (cm) and the slats' mass attenuation (cm2/g; lead's density from the
        material database).
    paper : str
        Where the paper shows it.
    advanced_valid : bool
        Whether the geometry satisfies the advanced model's ``a, b >= h tan theta``.
    """

    name: str
    title: str
    a: float
    b: float
    c: float
    h: float
    theta_deg: float
    phi_deg: tuple[float, ...] = (32.0, 127.0)
    detectors: tuple[tuple[float, float], ...] = ((0.0, 0.0), (8.4, 4.85))
    L: float = 100.0
    sigma: float = PAPER_SIGMA_662
    paper: str = ""
    advanced_valid: bool = True

    def instrument(self) -> Instrument:
        """The scenario's instrument (lead with the fixed 662 keV attenuation)."""
        mat = Material("lead", mass_attenuation=self.sigma)
        return Instrument(
            Mask(self.a, self.b, self.h, self.L, mat),
            DetectorArray(np.array(self.detectors, dtype=float), self.c),
        )

    @property
    def theta(self) -> u.Quantity:
        """Source zeniths, one per azimuth."""
        return np.full(len(self.phi_deg), self.theta_deg) * u.deg

    @property
    def phi(self) -> u.Quantity:
        """Source azimuths."""
        return np.asarray(self.phi_deg, dtype=float) * u.deg


#: The validation scenarios by name, in the report's order.
SCENARIOS: Registry[Scenario] = Registry("scenario")
for _s in (
    Scenario("thick20", "a=b=c=4, h=20 cm, theta=6 deg (shadow lengthening)",
             4, 4, 4, 20.0, 6.0, paper="Fig. 4"),
    Scenario("wide50", "a=b=c=4, h=1 cm, theta=50 deg (clipping, low contrast)",
             4, 4, 4, 1.0, 50.0, paper="Fig. 5"),
    Scenario("gap12", "b=12, a=c=4, h=2 cm, theta=10 deg (saturated transmission)",
             4, 12, 4, 2.0, 10.0, paper="Fig. 6 (h, theta ours)"),
    Scenario("slat12", "a=12, b=c=4, h=2 cm, theta=10 deg (dead time)",
             12, 4, 4, 2.0, 10.0, paper="Fig. 7 (h, theta ours)"),
    Scenario("det12", "c=12, a=b=4, h=2 cm, theta=10 deg (two slats over a detector)",
             4, 4, 12, 2.0, 10.0, paper="Fig. 8 (h, theta ours)"),
    Scenario("thin5mm", "a=b=c=4, h=0.5 cm at 662 keV, theta=6 deg (55 % slat transmission)",
             4, 4, 4, 0.5, 6.0, paper="Fig. 10 set-up"),
    Scenario("zen48", "a=b=c=4, h=2 cm, theta=48 deg (large zenith)",
             4, 4, 4, 2.0, 48.0, paper="Fig. 11 set-up"),
    Scenario("a_lt_htan", "a=1, b=c=4, h=10 cm, theta=20 deg (a < h tan theta)",
             1, 4, 4, 10.0, 20.0, paper="outside advanced validity", advanced_valid=False),
    Scenario("b_lt_htan", "b=1, a=c=4, h=6 cm, theta=30 deg (b < h tan theta)",
             4, 1, 4, 6.0, 30.0, paper="outside advanced validity", advanced_valid=False),
    Scenario("two_slats", "a=b=2, c=4, h=10 cm, theta=30 deg (rays cross two slats)",
             2, 2, 4, 10.0, 30.0, paper="outside advanced validity", advanced_valid=False),
    Scenario("thick45", "a=b=c=4, h=10 cm, theta=45 deg (h tan theta > a + b)",
             4, 4, 4, 10.0, 45.0, paper="outside advanced validity", advanced_valid=False),
):
    SCENARIOS.register(_s.name, _s)


def get_scenario(name: str) -> Scenario:
    """The scenario called ``name``.

    Raises
    ------
    ParameterError
        Unknown name; the message lists the known ones and suggests the closest.
    """
    return SCENARIOS.get(name)


def chi_square(model: np.ndarray, counts: np.ndarray, n_photons: int) -> tuple[float, float]:
    """Pearson chi-square of MC ``counts`` (of ``n_photons`` each) against ``model`` P.

    The variance is the model's binomial ``P (1 - P) / N`` with ``P`` clipped to
    ``[1/(2N), 1 - 1/(2N)]``.

    Returns
    -------
    chi2 : float
    dof : float
        Effective degrees of freedom: the chi-square expected if the model were true,
        ``sum P (1 - P) / (p (1 - p))`` with ``p`` the clipped ``P``.  Each cell with
        ``N P (1 - P) >~ 1`` counts 1; cells a model calls certain (``P`` = 0 or 1, or
        nearly) count little or nothing, so a correct model has ``chi2 / dof`` near 1.
    """
    n = float(n_photons)
    P = np.asarray(model, dtype=float)
    p = np.clip(P, 0.5 / n, 1.0 - 0.5 / n)
    f = np.asarray(counts) / n
    var = p * (1.0 - p)
    chi2 = float(np.sum((f - P) ** 2 / (var / n)))
    dof = float(np.sum(np.clip(P, 0.0, 1.0) * (1.0 - np.clip(P, 0.0, 1.0)) / var))
    return chi2, dof


@dataclass
class ScenarioResult:
    """The Monte Carlo and every model for one scenario.

    Attributes
    ----------
    scenario : Scenario
    xi : ndarray
        Mask angles (rad).
    mc : MCProfiles
        Monte Carlo profiles ``[d, t, n]`` with binomial errors.
    profiles : dict of str to ndarray
        Each applicable model's ``P[d, t, n]``.
    skipped : dict of str to str
        Models not evaluated, with the reason.
    chi2, dof, chi2_dof, max_dev : dict of str to float
        Chi-square, effective degrees of freedom (see :func:`chi_square`), their ratio and
        the largest absolute deviation from the MC, per model.
    resolution : float
        Chi-square excess per dof that a model off the exact one by 0.5 % of the
        unobstructed flux (0.005 in P) would add: the power of this comparison (well above
        ``sqrt(2 / dof)`` means a 0.5 % error is resolved).
    """

    scenario: Scenario
    xi: np.ndarray
    mc: MCProfiles
    profiles: dict[str, np.ndarray] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    chi2: dict[str, float] = field(default_factory=dict)
    dof: dict[str, float] = field(default_factory=dict)
    chi2_dof: dict[str, float] = field(default_factory=dict)
    max_dev: dict[str, float] = field(default_factory=dict)
    resolution: float = float("nan")


def run_scenario(
    scenario: Scenario | str,
    *,
    n_photons: int = 100_000,
    n_angles: int = 360,
    models: tuple[str, ...] = VALIDATION_MODELS,
    seed: Any = 0,
) -> ScenarioResult:
    """Run the Monte Carlo and every applicable model for one scenario.

    Parameters
    ----------
    scenario : Scenario or str
        A scenario or the name of one in :data:`SCENARIOS`.
    n_photons : int
        Monte Carlo photons per (detector, angle, source) cell.
    n_angles : int
        Mask angles, evenly spaced over one turn.
    models : tuple of str
        Registry names of the models to compare, default the validation's selection
        (unregistered ones are skipped).
    seed : int, SeedSequence, Generator or None
        Monte Carlo seed.

    Returns
    -------
    ScenarioResult
    """
    sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
    if not isinstance(sc, Scenario):
        raise ParameterError(f"scenario must be a Scenario or a name, got {type(sc)}")
    as_int(n_angles, "n_angles", 1)
    inst = sc.instrument()
    # Bin centres: an angle grid that avoids the exact-alignment angles xi + phi = pi/2 of
    # the scenarios' round azimuths.
    xi = (np.arange(int(n_angles)) + 0.5) * (2 * np.pi / int(n_angles))  # rad
    mc = simulate_profiles(inst, sc.theta, sc.phi, xi * u.rad, n_photons=n_photons, seed=seed)
    res = ScenarioResult(sc, xi, mc)
    for name in models:
        if name not in MODELS:
            res.skipped[name] = "not registered"
            continue
        try:
            P = get_model(name).profile(inst, sc.theta, sc.phi, xi * u.rad)
        except ModelValidityError as exc:
            res.skipped[name] = str(exc)
            continue
        res.profiles[name] = P
        res.chi2[name], res.dof[name] = chi_square(P, mc.counts, mc.n_photons)
        res.chi2_dof[name] = res.chi2[name] / max(res.dof[name], 1.0)
        res.max_dev[name] = float(np.max(np.abs(P - mc.fraction)))
    ref = res.profiles.get(REFERENCE_MODEL, mc.fraction)
    off = ref + 0.005 * np.sign(0.5 - ref + 1e-300)
    shifted, _ = chi_square(off, np.round(ref * mc.n_photons), mc.n_photons)
    _, dof = chi_square(ref, mc.counts, mc.n_photons)
    res.resolution = shifted / max(dof, 1.0)
    return res


def plot_scenario(
    result: ScenarioResult,
    *,
    detector: int = 0,
    source: int = 0,
    models: tuple[str, ...] = DEFAULT_COMPARISON,
    ax: Any = None,
) -> Any:
    """Draw MC vs models for one detector and source, like the paper's profile figures.

    Parameters
    ----------
    result : ScenarioResult
    detector, source : int
        Which profile to draw.
    models : tuple of str
        Models drawn (those that were evaluated).
    ax : matplotlib Axes, optional
        Axes to draw on; a new figure when None.

    Returns
    -------
    matplotlib.axes.Axes
    """
    sc = result.scenario
    x0, y0 = sc.detectors[detector]
    shown = [m for m in models if m in result.profiles]
    return plot_profiles(
        result.xi * u.rad, {m: result.profiles[m][detector, :, source] for m in shown},
        mc=result.mc.fraction[detector, :, source], mc_error=result.mc.error[detector, :, source],
        labels={m: f"{m} (χ²/dof {result.chi2_dof[m]:.3g})" for m in shown},
        title=f"{sc.name}: {sc.title}; det ({x0:g}, {y0:g}) cm, φ = {sc.phi_deg[source]:g}°",
        ax=ax,
    )

