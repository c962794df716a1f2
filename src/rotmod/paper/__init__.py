"""The seed paper's experiments in one place: its scenarios, the profile validation against
the Monte Carlo, what the paper claims, and the ``rotmod reproduce`` report.

Instruments come from the presets (:func:`rotmod.io.load_instrument`).
"""

from rotmod.paper.report import SIZES, STEPS, ReproduceResult, reproduce
from rotmod.paper.scenarios import SCENARIOS, Scenario, make_scenario

__all__ = ["SCENARIOS", "SIZES", "STEPS", "ReproduceResult", "Scenario", "make_scenario",
           "reproduce"]
