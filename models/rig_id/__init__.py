"""Identification of a rig's plant for the bring-up: excitation runs within safety limits
(:mod:`.excitation`), the logged runs (:mod:`.runs`), the fits with their uncertainties
(:mod:`.fits`, :mod:`.friction`) and the whole identification (:mod:`.identify`).
The API the bring-up calls is described in INTERFACE.md."""

from capstan.models.rig_id.excitation import Excitation, ExcitationLimits, free_excitation, held_excitation
from capstan.models.rig_id.fits import Estimate
from capstan.models.rig_id.identify import RigGeometry, RigIdentification, identify_rig
from capstan.models.rig_id.runs import RigRun

__all__ = ["Estimate", "Excitation", "ExcitationLimits", "RigGeometry", "RigIdentification", "RigRun",
           "free_excitation", "held_excitation", "identify_rig"]
