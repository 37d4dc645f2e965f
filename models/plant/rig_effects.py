"""Physical effects injected into the simulated rig (:class:`capstan.models.plant.rig.SimulatedRig`),
for hardware-in-the-loop runs whose plant carries an effect the controller's model lacks.

Config (the ``effects`` list of a rig ``plant`` section; names and default strengths as
:data:`capstan.models.plant.effect_plant.DEFAULTS`)::

    effects:
      - {effect: dwell_stiction, amp: 1.0, tau_age_s: 1.0, slide_rad: 0.05}
      - {effect: position_friction, a1_1_rad: 0.5, a2_1_rad2: 0.6}

Each effect scales mu of every sheath node of the distributed transmission
(``DistributedModel.mu_scale``) by the multiplier of :mod:`capstan.models.plant.injected_friction`,
evaluated on the true plant state before each step: the same physics as the simulated
testbed, acting on the distributed friction instead of the reduced model's tau_fc.
Several effects multiply.

Supported on the rig: dwell_stiction, position_friction, load_friction (``|tau_in|``
the cable torque at the input pulley), friction_ripple. The others are not friction
multipliers of the rig's physics (pretension relaxation lowers the tensions the load
cells measure, latency and stiffness are not friction) and are refused.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from capstan.models.common.config_tools import get_float
from capstan.models.distributed.model import DistributedModel
from capstan.models.plant.effect_plant import DEFAULTS, INJECTABLE
from capstan.models.common.errors import ConfigError
from capstan.models.plant.injected_friction import PLANT_V_REST_RAD_S, friction_multiplier, plant_dwell_step

#: effects the simulated rig can carry
RIG_EFFECTS = ("dwell_stiction", "position_friction", "load_friction", "friction_ripple")


@dataclass(frozen=True)
class RigEffect:
    """One injected effect: its name, kind (index in INJECTABLE) and parameters.

    :ivar params: the named parameters (keys of :data:`capstan.models.plant.effect_plant.DEFAULTS`).
    """

    name: str
    kind: int
    params: dict[str, float]

    @property
    def packed(self) -> tuple[float, float, float]:
        """The parameters in DEFAULTS order, padded to three."""
        vals = [self.params[k] for k in DEFAULTS[self.name]] + [1.0, 1.0, 1.0]
        return float(vals[0]), float(vals[1]), float(vals[2])

    @staticmethod
    def from_mapping(cfg: Any, prefix: str) -> "RigEffect":
        """``{effect: NAME, <param>: value, ...}``; absent parameters take the defaults.

        :raises ConfigError: on an unknown or unsupported effect, unknown keys or bad values.
        """
        if not isinstance(cfg, Mapping):
            raise ConfigError(prefix, f"must be a mapping with 'effect', got {type(cfg).__name__}")
        name = cfg.get("effect")
        if name not in RIG_EFFECTS:
            raise ConfigError(f"{prefix}.effect", f"must be one of {', '.join(RIG_EFFECTS)}, got {name!r}")
        defaults = DEFAULTS[name]
        unknown = sorted(set(cfg) - {"effect"} - set(defaults))
        if unknown:
            raise ConfigError(f"{prefix}.{unknown[0]}", f"unknown key; {name} takes {', '.join(defaults)}")
        params = {}
        for k, d in defaults.items():
            positive = k.endswith("_s") or k in ("slide_rad", "period_rad")    # time constants, lengths
            params[k] = get_float(cfg, k, prefix, d, min_value=0.0 if positive else None, min_exclusive=positive)
        return RigEffect(name, INJECTABLE.index(name), params)


class RigEffects:
    """The injected effects of one rig and the plant-side state they need (dwell).

    :param effects: the effects (may be empty: then the rig is the plain model).
    """

    def __init__(self, effects: Sequence[RigEffect]) -> None:
        self.effects = tuple(effects)
        self._packed = [(e.kind, *e.packed) for e in self.effects]
        self.reset()

    @staticmethod
    def from_list(cfg: Any, prefix: str = "plant.effects") -> "RigEffects":
        """Parse the ``effects`` list.

        :raises ConfigError: naming the offending entry and key.
        """
        if cfg is None:
            return RigEffects(())
        if not isinstance(cfg, list):
            raise ConfigError(prefix, f"must be a list of effects, got {type(cfg).__name__}")
        return RigEffects([RigEffect.from_mapping(e, f"{prefix}[{i}]") for i, e in enumerate(cfg)])

    def __bool__(self) -> bool:
        return bool(self.effects)

    def reset(self) -> None:
        """Back to a long rest before t = 0."""
        self.dwell_s, self.rest_s, self.slide_rad = 10.0, 10.0, 0.0
        self.multiplier = 1.0

    def before_step(self, model: DistributedModel) -> None:
        """Set the friction multiplier of every node from the current state."""
        m = 1.0
        q = model.q_out_rad
        for kind, p0, p1, p2 in self._packed:
            m *= friction_multiplier(kind, p0, p1, p2, q, self.rest_s, self.slide_rad, model.t_s,
                                     model.tau_in_Nm, 25.0)
        self.multiplier = max(m, 0.0)
        model.mu_scale[:] = self.multiplier

    def after_step(self, model: DistributedModel, dt_s: float) -> None:
        """Update the dwell bookkeeping with the new true output velocity."""
        self.dwell_s, self.rest_s, self.slide_rad = plant_dwell_step(
            self.dwell_s, self.rest_s, self.slide_rad, model.dq_out_rad_s, dt_s, PLANT_V_REST_RAD_S)

    def describe(self) -> list[dict[str, Any]]:
        """The effects as config mappings (for logs and reports)."""
        return [{"effect": e.name, **e.params} for e in self.effects]
