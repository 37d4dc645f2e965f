"""Gains for an identified rig (the bring-up's *tune* step), chosen with the loop model: the
identified plant in the controller section (:mod:`.plant_section`) and the most transparent
gains the start-up check passes (:mod:`.search`, whose docstring describes the method)."""

from capstan.controller.law.tuning.plant_section import plant_controller, solve_mu
from capstan.controller.law.tuning.search import TuningResult, tune_controller

__all__ = ["TuningResult", "plant_controller", "solve_mu", "tune_controller"]
