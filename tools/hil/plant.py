"""The simulated rig as its own process: plant in real time + simulated drive, IMU and load cells.

Started by ``capstan hil`` (``python -m capstan.tools.hil.plant --config hil.yaml --channel DIR``):

* the plant (:class:`capstan.models.plant.rig.SimulatedRig`, section ``hil.plant``) advances on
  absolute 1 ms deadlines; after a late wake-up it integrates the real elapsed time,
  so simulated time follows the wall clock;
* the drive (:class:`capstan.drivers.sim.drive.SimDrive`) sits on the cross-process CAN bus
  ``capstan_unix`` at ``DIR``; its torque command drives the motor inertia and the
  plant's motor state goes back in its TPDOs; it watches the daemon's heartbeat;
* the IMU (:class:`capstan.drivers.sim.serial_devices.SimXsens`) and the load-cell amplifier
  (:class:`capstan.drivers.sim.serial_devices.SimLoadCellAmp`) write real wire bytes into pty pairs;
* an external torque ``hil.tau_ext`` (an open-loop sine) acts on the output, and/or a
  hand ``hil.hand`` (:mod:`capstan.tools.hil.hand`: an arm impedance moving the link with rests,
  holding the handle while the drive is enabled) whose interaction torque is measured;
* the plant may carry effects the controller's model lacks (``hil.plant.effects``,
  :mod:`capstan.models.plant.rig_effects`);
* the devices report what real ones report (``hil.plant.sensors``,
  :mod:`capstan.models.plant.sensors`; realistic unless ``sensors: ideal``): the drive's
  position and velocity as the drive forms them (``SimulatedRig.motor_feedback``), the IMU
  with bias and misalignment, the load cells with calibration errors and drift.

Protocol with the parent on stdout: one JSON line once ready
``{"channel", "imu_port", "load_cells_port", "pid"}``; one JSON line of statistics at the
end (with ``hand``: the interaction-torque statistics, ``effects``: the injected effects,
``devices``: the device models).
It stops on SIGTERM, :data:`ORPHAN_GRACE_S` after its parent dies (a real rig outlives a
killed daemon: the drive's own heartbeat watch must get to act first), or on a plant error
(cable slack, integrator failure: exit code 4). SIGINT is ignored — the daemon must ramp down first.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import shutil
import signal
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from capstan.controller.runtime import realtime
from capstan.controller.runtime.realtime import RealtimeMode, RealtimeSettings
from capstan.controller.runtime.timing import DeadlineSleeper, process_cpu_s
from capstan.drivers.canopen.cia402 import State402
from capstan.drivers.serial.xsens_config import BAUD_CODES
from capstan.models.common.config_tools import get_choice, get_float, get_int, load_yaml, reject_unknown, section
from capstan.models.common.errors import CapstanError, ConfigError, ModelError
from capstan.tools.hil.hand import Hand, HandSettings

log = logging.getLogger("capstan.hil_plant")

EXIT_PLANT_ERROR = 4
#: how long the simulated rig keeps running after the daemon is gone [s]: longer than any
#: consumer heartbeat time a config may set (motor.consumer_timeout_s ≤ 1 s), so the drive's
#: own watch acts first, as on a rig
ORPHAN_GRACE_S = 1.5


@dataclass(frozen=True)
class HilSettings:
    """The ``hil`` section (besides ``plant``, validated by SimulatedRig).

    :ivar period_s: plant step / pacing period [s].
    :ivar max_catch_up_s: longest interval integrated in one step after a stall [s].
    :ivar tau_ext_amplitude_Nm: amplitude of the external sine torque on the link [Nm].
    :ivar tau_ext_frequency_hz: its frequency [Hz].
    :ivar rated_torque_Nm: the simulated drive's rated torque (0x6076) [Nm].
    :ivar realtime: scheduling of the plant process.
    :ivar hand: the hand moving the link (None: no hand).
    :ivar imu_boot_baudrate: line rate the simulated MTi boots at (``hil.imu.boot_baudrate``,
        default 115200 like a new unit, so the daemon's start-up searches the rate) [Bd].
    """

    period_s: float = 1e-3
    max_catch_up_s: float = 0.01
    tau_ext_amplitude_Nm: float = 0.0
    tau_ext_frequency_hz: float = 0.5
    rated_torque_Nm: float = 20.0
    realtime: RealtimeSettings = RealtimeSettings(mode=RealtimeMode.WARN, priority=70, lock_memory=False,
                                                  helper_priority=69)
    hand: HandSettings | None = None
    imu_boot_baudrate: int = 115200

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], prefix: str = "hil") -> "HilSettings":
        """:raises ConfigError: naming the offending key."""
        reject_unknown(cfg, {"plant", "period_s", "max_catch_up_s", "tau_ext", "drive", "realtime", "hand", "imu"},
                       prefix)
        imu = section(cfg, "imu", prefix, required=False)
        reject_unknown(imu, {"boot_baudrate"}, f"{prefix}.imu")
        boot_bd = get_int(imu, "boot_baudrate", f"{prefix}.imu", 115200)
        if boot_bd not in BAUD_CODES:
            raise ConfigError(f"{prefix}.imu.boot_baudrate", f"{boot_bd} Bd is not an MTi rate; one of "
                                                             f"{', '.join(str(b) for b in sorted(BAUD_CODES))}")
        d = HilSettings()
        te = section(cfg, "tau_ext", prefix, required=False)
        reject_unknown(te, {"amplitude_Nm", "frequency_hz"}, f"{prefix}.tau_ext")
        dr = section(cfg, "drive", prefix, required=False)
        reject_unknown(dr, {"rated_torque_Nm"}, f"{prefix}.drive")
        rt = section(cfg, "realtime", prefix, required=False)
        rp = f"{prefix}.realtime"
        reject_unknown(rt, {"mode", "priority", "cpus"}, rp)
        cpus = rt.get("cpus") or []
        if not isinstance(cpus, list) or not all(isinstance(c, int) and c >= 0 for c in cpus):
            raise ConfigError(f"{rp}.cpus", f"must be a list of CPU numbers >= 0, got {cpus!r}")
        prio = get_int(rt, "priority", rp, 70, 2, 99)
        return HilSettings(
            get_float(cfg, "period_s", prefix, d.period_s, min_value=1e-4, max_value=0.01),
            get_float(cfg, "max_catch_up_s", prefix, d.max_catch_up_s, min_value=1e-4, max_value=0.1),
            get_float(te, "amplitude_Nm", f"{prefix}.tau_ext", 0.0, min_value=0.0),
            get_float(te, "frequency_hz", f"{prefix}.tau_ext", d.tau_ext_frequency_hz, min_value=0.0),
            get_float(dr, "rated_torque_Nm", f"{prefix}.drive", d.rated_torque_Nm, min_value=0.0,
                      min_exclusive=True),
            RealtimeSettings(RealtimeMode.parse(get_choice(rt, "mode", ("off", "warn", "enforce"), rp, "warn")),
                             prio, tuple(cpus), lock_memory=False, gil_switch_interval_s=0.0,
                             helper_priority=prio - 1),
            HandSettings.from_mapping(section(cfg, "hand", prefix), f"{prefix}.hand") if "hand" in cfg else None,
            boot_bd,
        )


class HilPlant:
    """The rig process's objects, built from a full daemon config mapping.

    :param cfg: the whole config (``hil`` plus the device sections the drivers use, so
        the simulated devices match the drivers' scaling exactly).
    :param channel: the ``capstan_unix`` bus directory.
    :raises ConfigError: on an invalid ``hil`` or device section.
    """

    def __init__(self, cfg: Mapping[str, Any], channel: str) -> None:
        import can

        from capstan.drivers.canopen.config import MotorConfig
        from capstan.drivers.sim.drive import SimDrive
        from capstan.drivers.sim.serial_devices import SimLoadCellAmp, SimXsens, open_pty_pair
        from capstan.models.plant.rig import SimulatedRig

        hil = section(cfg, "hil")
        self.settings = HilSettings.from_mapping(hil)
        self.rig = SimulatedRig.from_mapping(section(hil, "plant", "hil"), "hil.plant")
        mcfg = MotorConfig.from_mapping({k: v for k, v in section(cfg, "motor").items() if k != "backend"})
        imu_cfg = {k: v for k, v in section(cfg, "imu").items() if k != "backend"}
        lc_cfg = {k: v for k, v in section(cfg, "load_cells").items() if k != "backend"}
        self.imu_pty = open_pty_pair()
        self.lc_pty = open_pty_pair()
        self.imu = SimXsens.from_config(self.imu_pty.master_fd, {**imu_cfg, "port": self.imu_pty.slave_path},
                                        boot_baudrate=self.settings.imu_boot_baudrate)
        self.cells = SimLoadCellAmp.from_config(self.lc_pty.master_fd, {**lc_cfg, "port": self.lc_pty.slave_path})
        self.channel = channel
        #: True once :meth:`run` stopped because its parent was gone
        self.orphaned = False
        self.bus = can.Bus(interface="capstan_unix", channel=channel)
        self.drive = SimDrive(self.bus, mcfg.node_id, mcfg.eds, self.settings.rated_torque_Nm,
                              mcfg.encoder_counts_per_rev, mcfg.velocity_units_per_rev_s)
        self._gear = mcfg.gear_ratio
        self.hand = Hand(self.settings.hand) if self.settings.hand is not None else None
        self._hand_t0_s: float | None = None
        self.steps = 0
        self.lost_s = 0.0
        self.step_us = np.zeros(1 << 16)
        self.stop = False

    def ports(self) -> dict[str, Any]:
        """The handshake line: where the daemon finds the devices."""
        return {"channel": self.channel, "imu_port": self.imu_pty.slave_path,
                "load_cells_port": self.lc_pty.slave_path, "pid": os.getpid()}

    def tau_ext_Nm(self, t_s: float) -> float:
        """External torque on the link at simulated time ``t_s`` [Nm]."""
        s = self.settings
        return s.tau_ext_amplitude_Nm * math.sin(2 * math.pi * s.tau_ext_frequency_hz * t_s)

    def hand_torque_Nm(self, t_s: float, dt_s: float) -> float:
        """Interaction torque of the hand over the next ``dt_s`` (0 without a hand or while
        the drive is not enabled) [Nm]; recorded in the hand's statistics."""
        if self.hand is None or self.drive.state != State402.OPERATION_ENABLED:
            return 0.0
        if self._hand_t0_s is None:
            self._hand_t0_s = t_s
        m = self.rig.model
        th = t_s - self._hand_t0_s
        tau_h = self.hand.torque_Nm(th, m.q_out_rad, m.dq_out_rad_s)
        self.hand.record(th, tau_h, dt_s)
        return tau_h

    def cycle(self, dt_s: float, now_s: float) -> None:
        """One plant period: drive command -> plant -> feedback, sensors out.

        :raises ModelError: if the plant leaves its range (cable slack) or fails.
        """
        tau_m = self.drive.torque_command_Nm
        t = self.rig.t_s
        self.rig.step(tau_m, self.tau_ext_Nm(t) + self.hand_torque_Nm(t, dt_s), dt_s)
        q, dq, tau = self.rig.motor_feedback()
        self.drive.set_feedback(q * self._gear, dq * self._gear, tau)
        self.drive.service(now_s)
        self.imu.service()
        self.cells.service()
        new, q_out, dq_out = self.rig.imu_sample()
        if new:
            self.imu.emit(self.rig.t_s, q_out, dq_out)
        self.cells.emit(self.rig.load_cells_N())

    def run(self, parent_pid: int = 0) -> dict[str, Any]:
        """Pace :meth:`cycle` in real time until :attr:`stop`, or the parent is gone.

        :raises ModelError: on a plant error.
        """
        s = self.settings
        sl = DeadlineSleeper(s.period_s, busy_tail_s=0.0)
        period_ns = sl.period_ns
        cap_ns = max(period_ns, int(s.max_catch_up_s * 1e9) // period_ns * period_ns)
        t0 = sl.start() - period_ns
        sim_ns = 0                      # simulated time integrated so far, on the wall grid
        self.lost_s = 0.0
        cpu0 = process_cpu_s()
        wall0 = time.monotonic()
        orphan_since_s: float | None = None
        while not self.stop:
            wake, _late = sl.wait()
            due_ns = (wake - t0) - sim_ns
            dt_ns = min(max(due_ns // period_ns, 1) * period_ns, cap_ns)
            sim_ns += dt_ns
            if (wake - t0) - sim_ns > cap_ns:     # a stall longer than the catch-up bound
                self.lost_s += ((wake - t0) - sim_ns) * 1e-9
                sim_ns = (wake - t0) // period_ns * period_ns
            a = time.monotonic_ns()
            self.cycle(dt_ns * 1e-9, wake * 1e-9)
            self.step_us[self.steps % len(self.step_us)] = (time.monotonic_ns() - a) * 1e-3
            self.steps += 1
            if parent_pid and self.steps % 50 == 0 and os.getppid() != parent_pid:
                if orphan_since_s is None:
                    orphan_since_s = time.monotonic()
                    log.warning("parent %d is gone; stopping the simulated rig in %.1f s",
                                parent_pid, ORPHAN_GRACE_S)
                elif time.monotonic() - orphan_since_s >= ORPHAN_GRACE_S:
                    self.orphaned = True
                    break
        n = min(self.steps, len(self.step_us))
        st = self.step_us[:n]
        wall = time.monotonic() - wall0
        return {"steps": self.steps, "overruns": sl.overruns, "missed": sl.missed,
                "sim_time_s": self.rig.t_s, "wall_s": wall, "lost_s": self.lost_s,
                "step_p99_us": float(np.percentile(st, 99)) if n else math.nan,
                "step_max_us": float(st.max()) if n else math.nan,
                "cpu_s": process_cpu_s() - cpu0,
                "drive_faults": [hex(c) for c in self.drive.faults_raised],
                "hand": self.hand.stats() if self.hand is not None else None,
                "effects": self.rig.effects.describe(),
                "devices": self.rig.devices.label}

    def close(self) -> None:
        """Release the bus and the ptys."""
        for action in (self.drive.close, self.bus.shutdown, self.imu_pty.close, self.lc_pty.close):
            try:
                action()
            except Exception as exc:  # noqa: BLE001 - release everything
                log.debug("close: %s", exc)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m capstan.tools.hil.plant``; returns the exit code."""
    p = argparse.ArgumentParser(prog="python -m capstan.tools.hil.plant", description=__doc__.split("\n")[0])
    p.add_argument("--config", required=True, help="HIL config YAML (sections hil, motor, imu, load_cells)")
    p.add_argument("--channel", required=True, help="capstan_unix bus directory")
    p.add_argument("--parent-pid", type=int, default=0, help="stop when this process is gone")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s hil_plant: %(message)s")
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        plant = HilPlant(load_yaml(args.config), args.channel)
    except CapstanError as exc:
        log.error("%s", exc)
        return 2

    def _on_term(signum: int, frame: Any) -> None:
        plant.stop = True

    signal.signal(signal.SIGTERM, _on_term)
    code = 0
    try:
        plant.rig.step(0.0, 0.0, plant.settings.period_s)   # compile the plant before READY
        rts = plant.settings.realtime
        rep = realtime.prepare(rts)
        realtime.apply_to_threads(rts, rep, [t for t in threading.enumerate() if t is not threading.current_thread()])
        realtime.apply(rts, rep)
        print(json.dumps(plant.ports()), flush=True)
        stats = plant.run(args.parent_pid)
    except ModelError as exc:
        log.error("plant error: %s", exc)
        stats, code = {"error": str(exc), "steps": plant.steps}, EXIT_PLANT_ERROR
    finally:
        plant.close()
    if plant.orphaned:
        # the parent made the bus directory and would have removed it: nobody else will
        shutil.rmtree(args.channel, ignore_errors=True)
        log.info("removed the bus directory %s its parent left behind", args.channel)
    try:
        print(json.dumps(stats), flush=True)
    except BrokenPipeError:                     # the parent is gone and its pipe with it
        log.warning("statistics not delivered (stdout closed): %s", json.dumps(stats))
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second failure at exit
    return code


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
