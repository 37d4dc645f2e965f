"""The frozen configuration of the controller (the ``controller:`` YAML section).

Sections ``plant``, ``ldo``, ``feedback`` (:mod:`capstan.controller.law.feedback_config`),
``filters``, ``gravity``, ``feedforward``, ``safety`` (:mod:`capstan.controller.law.safety_config`)
and ``stability`` (:mod:`capstan.controller.law.stability_settings`). The defaults are the
dataclass fields below and in those modules, and nowhere else: every key with its unit, range,
default and meaning is in docs/configuration.md, generated from the parsers by
``capstan config reference``.

All numbers are SI. :meth:`ControllerConfig.to_mapping` returns the same structure
(with the routing as its curvature profile) so a log stores the exact config used.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from enum import IntEnum
from typing import Any, Mapping

from capstan.controller.law.feedback_config import AccelerationSource, FeedbackGains, feedback_from_mapping
from capstan.controller.law.learned_effects import check_entries
from capstan.controller.law.safety_config import SafetyConfig, safety_from_mapping
from capstan.controller.law.stability_settings import StabilitySettings, stability_from_mapping
from capstan.models.common.config_tools import get_bool, get_choice, get_float, reject_unknown, section
from capstan.models.common.errors import ConfigError
from capstan.models.transmission.pretension import Eq25Reading


class TorqueLoop(IntEnum):
    """The low-level torque controller."""

    PID = 0
    LDO = 1


class Placement(IntEnum):
    """Where the friction feedforward enters."""

    REFERENCE = 0   #: tau_in_des = (r_in/r_out)(tau_g + tau_fc)
    MOTOR = 1       #: added to tau_m, eq (28) as printed


class PretensionSource(IntEnum):
    """Where the friction magnitude's pretension comes from."""

    MEASURED = 0
    FIXED = 1


@dataclass(frozen=True)
class PlantNominal:
    """Nominal plant of eq (26)."""

    stiffness_Nm_rad: float = 240.0
    motor_inertia_kg_m2: float = 0.73
    motor_damping_Nms_rad: float = 0.5
    r_in_m: float = 0.04
    r_out_m: float = 0.04


@dataclass(frozen=True)
class FeedforwardConfig:
    """Reduced-model friction feedforward (eq 21) with the routing as a curvature profile.

    :ivar routing_profile: ``((s_m, kappa_1_per_m), ...)`` knots of the routing.
    :ivar routing_length_m: routing length [m].
    :ivar effects: learned effect entries (``capstan close`` fragment), validated.
    :ivar effects_shape: ``(alpha_s_rad, eta_s_rad_s, zeta_s, v_rest_rad_s)`` of the effects.
    """

    enabled: bool = True
    placement: Placement = Placement.REFERENCE
    gain: float = 1.0
    mu: float = 0.052
    routing_profile: tuple[tuple[float, float], ...] = ((0.0, 3.0 / 1.379), (1.379, 3.0 / 1.379))
    routing_length_m: float = 1.379
    pretension: PretensionSource = PretensionSource.MEASURED
    T0_fixed_N: float = 150.0
    eq25_reading: Eq25Reading = Eq25Reading.FRICTION_PRESERVING
    zeta_s: float = 1.2
    zeta_c: float = 1.0
    eta_s_rad_s: float = 0.05
    alpha_s_rad: float = 50.0
    b_vis_Nms_rad: float = 0.0
    dead_band_rad_s: float = 0.01
    max_rate_Nm_s: float = 200.0     # slew limit of the feedforward [Nm/s] (step.py)
    effects: tuple[dict[str, Any], ...] = ()
    effects_shape: tuple[float, float, float, float] = (50.0, 0.05, 1.2, 0.005)

    def routing(self) -> Any:
        """The :class:`capstan.models.transmission.routing.Routing` of this feedforward."""
        from capstan.models.transmission.routing import Routing
        s = [p[0] for p in self.routing_profile]
        k = [p[1] for p in self.routing_profile]
        return Routing.from_curvature_samples(s, k, self.routing_length_m)


@dataclass(frozen=True)
class ControllerConfig:
    """Frozen controller configuration; build with :meth:`from_mapping`."""

    dt_s: float = 0.001
    torque_loop: TorqueLoop = TorqueLoop.PID
    plant: PlantNominal = field(default_factory=PlantNominal)
    q_cutoff_hz: float = 10.0
    feedback: FeedbackGains = field(default_factory=FeedbackGains)
    tau_in_cutoff_hz: float = 150.0
    gravity_enabled: bool = True
    m_g_l_Nm: float = 3.78
    feedforward: FeedforwardConfig = field(default_factory=FeedforwardConfig)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    stability: StabilitySettings = field(default_factory=StabilitySettings)
    q_out_blend_hz: float = 2.0

    # ------------------------------------------------------------------ parsing
    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str = "controller") -> "ControllerConfig":
        """Validate and freeze a ``controller:`` mapping; absent keys take the defaults.

        :raises ConfigError: naming the dotted key and the reason (unknown key, wrong
            type, out of range, inconsistent limits).
        """
        if not isinstance(cfg, Mapping):
            raise ConfigError(prefix, f"must be a mapping, got {type(cfg).__name__}")
        reject_unknown(cfg, {"dt_s", "torque_loop", "plant", "ldo", "feedback", "filters", "gravity",
                             "feedforward", "safety", "stability"}, prefix)
        d = ControllerConfig()
        dt = get_float(cfg, "dt_s", prefix, d.dt_s, min_value=1e-5, max_value=0.1)
        nyq = 0.5 / dt
        loop = TorqueLoop[get_choice(cfg, "torque_loop", ("ldo", "pid"), prefix, "pid").upper()]

        p = f"{prefix}.plant"
        c = section(cfg, "plant", prefix, required=False)
        reject_unknown(c, {"stiffness_Nm_rad", "motor_inertia_kg_m2", "motor_damping_Nms_rad", "r_in_m", "r_out_m"}, p)
        plant = PlantNominal(
            get_float(c, "stiffness_Nm_rad", p, d.plant.stiffness_Nm_rad, min_value=0.0, min_exclusive=True),
            get_float(c, "motor_inertia_kg_m2", p, d.plant.motor_inertia_kg_m2, min_value=0.0, min_exclusive=True),
            get_float(c, "motor_damping_Nms_rad", p, d.plant.motor_damping_Nms_rad, min_value=0.0),
            get_float(c, "r_in_m", p, d.plant.r_in_m, min_value=0.0, min_exclusive=True),
            get_float(c, "r_out_m", p, d.plant.r_out_m, min_value=0.0, min_exclusive=True))

        p = f"{prefix}.ldo"
        c = section(cfg, "ldo", prefix, required=False)
        reject_unknown(c, {"q_cutoff_hz"}, p)
        q_fc = get_float(c, "q_cutoff_hz", p, d.q_cutoff_hz, min_value=0.0, min_exclusive=True,
                         max_value=0.25 * nyq)

        p = f"{prefix}.feedback"
        c = section(cfg, "feedback", prefix, required=False)
        fb = feedback_from_mapping(c, p, d.feedback, nyq)

        p = f"{prefix}.filters"
        c = section(cfg, "filters", prefix, required=False)
        reject_unknown(c, {"tau_in_cutoff_hz", "q_out_blend_hz"}, p)
        tau_fc_hz = get_float(c, "tau_in_cutoff_hz", p, d.tau_in_cutoff_hz, min_value=0.0, max_value=0.45 * nyq)
        blend_hz = get_float(c, "q_out_blend_hz", p, d.q_out_blend_hz, min_value=0.0, max_value=0.1 * nyq)

        p = f"{prefix}.gravity"
        c = section(cfg, "gravity", prefix, required=False)
        reject_unknown(c, {"enabled", "m_g_l_Nm"}, p)
        g_on = get_bool(c, "enabled", p, d.gravity_enabled)
        mgl = get_float(c, "m_g_l_Nm", p, d.m_g_l_Nm, min_value=0.0)

        ff = _feedforward_from_mapping(section(cfg, "feedforward", prefix, required=False), f"{prefix}.feedforward")
        safety = safety_from_mapping(section(cfg, "safety", prefix, required=False), f"{prefix}.safety")
        stab = stability_from_mapping(section(cfg, "stability", prefix, required=False), f"{prefix}.stability")
        if ff.enabled and ff.dead_band_rad_s < 2.0 * stab.gyro_noise_rad_s:
            raise ConfigError(f"{prefix}.feedforward.dead_band_rad_s",
                              f"must be >= 2 x the gyro noise {stab.gyro_noise_rad_s} rad/s "
                              f"({prefix}.stability.gyro_noise_rad_s) so the friction direction cannot "
                              f"follow noise at rest, got {ff.dead_band_rad_s}")
        for key in ("inertia_comp_kg_m2", "deflection_damping_Nms_rad", "rest_gate_cutoff_hz"):
            if getattr(fb, key) > 0.0 and ff.dead_band_rad_s < 2.0 * stab.gyro_noise_rad_s:
                raise ConfigError(f"{prefix}.feedforward.dead_band_rad_s",
                                  f"must be >= 2 x the gyro noise {stab.gyro_noise_rad_s} rad/s while "
                                  f"{prefix}.feedback.{key} > 0: the rest band also keeps the gyro's "
                                  f"noise off the command at rest, got {ff.dead_band_rad_s}")
        j_min = plant.motor_inertia_kg_m2 * (1.0 - stab.inertia_tolerance)
        what = "J_m (1 - inertia_tolerance)"
        if fb.acceleration_source == AccelerationSource.LINK:     # motor and link move together
            j_min += stab.link_inertia_kg_m2
            what += " + stability.link_inertia_kg_m2"
        if fb.inertia_comp_kg_m2 >= j_min:
            raise ConfigError(f"{prefix}.feedback.inertia_comp_kg_m2",
                              f"must be below the smallest inertia the loop is checked for, {what} = "
                              f"{j_min:.3f} kg m^2 (the joint would feel no or negative inertia and run "
                              f"away), got {fb.inertia_comp_kg_m2}")
        j_link = stab.link_inertia_kg_m2 * (1.0 - stab.inertia_tolerance)
        if fb.link_inertia_comp_kg_m2 >= j_link:
            raise ConfigError(f"{prefix}.feedback.link_inertia_comp_kg_m2",
                              f"must be below the smallest link inertia the loop is checked for, "
                              f"stability.link_inertia_kg_m2 (1 - inertia_tolerance) = {j_link:.3f} kg m^2 (the "
                              f"hand would feel no or negative link inertia), got {fb.link_inertia_comp_kg_m2}")
        return ControllerConfig(dt, loop, plant, q_fc, fb, tau_fc_hz, g_on, mgl, ff, safety, stab,
                                q_out_blend_hz=blend_hz)

    def to_mapping(self) -> dict[str, Any]:
        """The YAML structure of :meth:`from_mapping` with every value explicit, such
        that ``from_mapping(to_mapping())`` reproduces this config exactly."""
        ff = self.feedforward
        return {
            "dt_s": self.dt_s,
            "torque_loop": self.torque_loop.name.lower(),
            "plant": asdict(self.plant),
            "ldo": {"q_cutoff_hz": self.q_cutoff_hz},
            "feedback": {**asdict(self.feedback),
                         "acceleration_source": self.feedback.acceleration_source.name.lower(),
                         "motor_velocity": self.feedback.motor_velocity.name.lower()},
            "filters": {"tau_in_cutoff_hz": self.tau_in_cutoff_hz, "q_out_blend_hz": self.q_out_blend_hz},
            "gravity": {"enabled": self.gravity_enabled, "m_g_l_Nm": self.m_g_l_Nm},
            "feedforward": {
                "enabled": ff.enabled, "placement": ff.placement.name.lower(), "gain": ff.gain,
                "mu": ff.mu,
                "routing": {"curvature_profile": [list(p) for p in ff.routing_profile],
                            "length_m": ff.routing_length_m},
                "pretension": ff.pretension.name.lower(), "T0_fixed_N": ff.T0_fixed_N,
                "eq25_reading": ff.eq25_reading.name.lower(),
                "zeta_s": ff.zeta_s, "zeta_c": ff.zeta_c, "eta_s_rad_s": ff.eta_s_rad_s,
                "alpha_s_rad": ff.alpha_s_rad, "b_vis_Nms_rad": ff.b_vis_Nms_rad,
                "dead_band_rad_s": ff.dead_band_rad_s, "max_rate_Nm_s": ff.max_rate_Nm_s,
                "effects": [dict(e) for e in ff.effects],
                "effects_shape": dict(zip(_EFFECTS_SHAPE_KEYS, ff.effects_shape)),
            },
            "safety": asdict(self.safety),
            "stability": {**asdict(self.stability),
                          "stiffness_range_Nm_rad": list(self.stability.stiffness_range_Nm_rad),
                          "grip_stiffness_Nm_rad": list(self.stability.grip_stiffness_Nm_rad)},
        }


#: keys of ``controller.feedforward.effects_shape``, in the order of ``FeedforwardConfig.effects_shape``
_EFFECTS_SHAPE_KEYS = ("alpha_s_rad", "eta_s_rad_s", "zeta_s", "v_rest_rad_s")


def _feedforward_from_mapping(c: Mapping[str, Any], p: str) -> FeedforwardConfig:
    """Parse ``controller.feedforward``.

    :raises ConfigError: naming the key.
    """
    from capstan.models.transmission.routing import Routing

    reject_unknown(c, {"enabled", "placement", "gain", "mu", "routing", "pretension",
                       "T0_fixed_N", "eq25_reading", "zeta_s", "zeta_c", "eta_s_rad_s", "alpha_s_rad", "b_vis_Nms_rad",
                       "dead_band_rad_s", "max_rate_Nm_s", "effects", "effects_shape"}, p)
    d = FeedforwardConfig()
    if "routing" in c:
        routing = Routing.from_mapping(section(c, "routing", p), f"{p}.routing")
        s_m, k = routing.curvature_profile()
        profile = tuple((float(a), float(b)) for a, b in zip(s_m, k))
        length = float(routing.length_m)
    else:
        profile, length = d.routing_profile, d.routing_length_m
    zeta_c = get_float(c, "zeta_c", p, d.zeta_c, min_value=0.0)
    zeta_s = get_float(c, "zeta_s", p, d.zeta_s, min_value=0.0)
    if zeta_s < zeta_c:
        raise ConfigError(f"{p}.zeta_s", f"must be >= zeta_c = {zeta_c}, got {zeta_s}")
    eta_s = get_float(c, "eta_s_rad_s", p, d.eta_s_rad_s, min_value=0.0, min_exclusive=True)
    alpha_s = get_float(c, "alpha_s_rad", p, d.alpha_s_rad, min_value=0.0, min_exclusive=True)
    effects = check_entries(c.get("effects", []), f"{p}.effects")
    es = section(c, "effects_shape", p, required=False)
    ep = f"{p}.effects_shape"
    reject_unknown(es, set(_EFFECTS_SHAPE_KEYS), ep)
    shape = (get_float(es, "alpha_s_rad", ep, alpha_s, min_value=0.0, min_exclusive=True),
             get_float(es, "eta_s_rad_s", ep, eta_s, min_value=0.0, min_exclusive=True),
             get_float(es, "zeta_s", ep, zeta_s),          # a fitted shape may dip below 0
             get_float(es, "v_rest_rad_s", ep, d.effects_shape[3], min_value=0.0, min_exclusive=True))
    return FeedforwardConfig(
        enabled=get_bool(c, "enabled", p, d.enabled),
        placement=Placement[get_choice(c, "placement", ("reference", "motor"), p, "reference").upper()],
        gain=get_float(c, "gain", p, d.gain, min_value=0.0, max_value=1.5),
        mu=get_float(c, "mu", p, d.mu, min_value=0.0, max_value=1.0),
        routing_profile=profile, routing_length_m=length,
        pretension=PretensionSource[get_choice(c, "pretension", ("measured", "fixed"), p, "measured").upper()],
        T0_fixed_N=get_float(c, "T0_fixed_N", p, d.T0_fixed_N, min_value=0.0),
        eq25_reading=Eq25Reading[get_choice(c, "eq25_reading", tuple(r.name.lower() for r in Eq25Reading), p,
                                            d.eq25_reading.name.lower()).upper()],
        zeta_s=zeta_s, zeta_c=zeta_c,
        eta_s_rad_s=eta_s, alpha_s_rad=alpha_s,
        b_vis_Nms_rad=get_float(c, "b_vis_Nms_rad", p, d.b_vis_Nms_rad, min_value=0.0),
        dead_band_rad_s=get_float(c, "dead_band_rad_s", p, d.dead_band_rad_s, min_value=0.0, max_value=1.0),
        max_rate_Nm_s=get_float(c, "max_rate_Nm_s", p, d.max_rate_Nm_s, min_value=0.0, min_exclusive=True),
        effects=effects, effects_shape=shape,
    )
