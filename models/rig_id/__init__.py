"""Identification of a rig's plant for the bring-up: excitation runs within safety limits
(:mod:`.excitation`), the logged runs (:mod:`.runs`) and the fits with their uncertainties
(:mod:`.identify`). See INTERFACE.md / docs/rig-identification for the workflow."""

from capstan.models.rig_id.excitation import Excitation, ExcitationLimits, free_excitation, held_excitation
from capstan.models.rig_id.runs import RigRun

__all__ = ["Excitation", "ExcitationLimits", "RigRun", "free_excitation", "held_excitation"]
