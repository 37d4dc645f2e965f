"""Measured multisine runs shared by the paper's Figs. 9-10 and 11.

The first figure to ask for a run pays for its simulation; the key is
``(group, output, plant, seed)`` with the plants of
:data:`capstan.tools.experiments.paper.common.PLANTS` plus ``"clean"`` (no unmodelled effects).
"""

from __future__ import annotations

from capstan.tools.experiments.paper.common import OUTPUTS, PLANTS, Run, Settings, group_routing, multisine, simulate_plant

PEAK_NM = 8.0        #: peak input torque of the shared multisine runs [Nm]


class RunCache:
    """Measured runs shared by the figures, keyed by (group, output, plant, seed)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self._runs: dict[tuple[int, str, str, int], Run] = {}

    def get(self, j: int, output: str, plant: str = "effects", seed: int | None = None) -> Run:
        """Multisine measured run of group ``j`` (0-based) with the named output and plant.

        :raises KeyError: on an unknown output or plant.
        :raises OperatingRangeError: on cable slack. :raises IntegrationError: on solver failure.
        """
        s = self.settings.seed if seed is None else int(seed)
        key = (j, output, plant, s)
        if key not in self._runs:
            effects, imbalanced = (False, False) if plant == "clean" else PLANTS[plant]
            self._runs[key] = simulate_plant(group_routing(j), multisine(PEAK_NM), self.settings, OUTPUTS[output],
                                             effects=effects, imbalanced=imbalanced, seed_offset=j, seed=s)
        return self._runs[key]
