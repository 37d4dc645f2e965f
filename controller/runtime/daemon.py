"""The capstan daemon: devices + controller + log, run as a 1 kHz read -> step -> write loop.

Life cycle (:meth:`Daemon.run`)::

    build      controller (Numba compiled and warmed), log sink, devices (drivers.registry)
    start      IMU, load cells, then the drive (SDO set-up, heartbeat consumer, enable)
    realtime   affinity, mlockall, SCHED_FIFO, GC frozen (controller.realtime)
    ARMING     cycles with zero torque until every device delivered fresh data -> READY=1
    RUNNING    read (drain, never block) -> step -> write (RPDO, SYNC) -> push record
    RAMPING    after SIGTERM/SIGINT or the end of ``duration_s``: the command is scaled
               linearly to zero over ``loop.ramp_down_s``, then the drive is disabled
    FAULTED    any fault bit (step or loop), a drive exception, a limit violation or an
               overrun streak: the same cycle sends zero torque, the drive is disabled,
               the last N cycles go to the log and the exception

Per cycle nothing is allocated beyond Python floats, nothing is logged (the timing
line is written once per ``stats_interval_s``), nothing waits on I/O.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import threading
import time
from typing import Any

import numpy as np

from capstan.controller.runtime import realtime
from capstan.controller.runtime.command_quality import CommandQuality
from capstan.controller.runtime.config import DaemonConfig
from capstan.controller.runtime.loop_checks import all_fresh, cpu_snapshot, limit_violation, rate_step_Nm, writer_is_lost
from capstan.controller.runtime.run_summary import Phase, RunSummary
from capstan.controller.runtime.link_report import device_links, fill_link_stats, link_status, link_summary
from capstan.controller.runtime.session_log import (STATS_DTYPE, LogSink, fill_stats, logged_config, newest_log,
                                                    open_session, send_derivations, wire_capable)
from capstan.controller.law.records import FaultBits, fault_names, loop_command
from capstan.controller.runtime.sd_notify import SdNotifier
from capstan.controller.runtime.timing import DeadlineSleeper, LoopStats, shared_abs_sleep
from capstan.drivers.interfaces import DeviceSet
from capstan.models.common.errors import (ControlFaultError, DeviceLostError, DeviceTimeoutError, DriverError,
                                          HeartbeatLostError)

log = logging.getLogger(__name__)

#: loop-detected limit violation (joint angle/rate, motor speed, tension); bit 12 of the
#: "outside the step" range of FaultBits
LIMIT_VIOLATION = int(FaultBits.LIMIT_VIOLATION)
#: a wake-to-wake interval above this many periods before a fault is named in the fault text
#: (the loop was not run: on a shared VM, a host stall stops the drive simulator too)
STALL_PERIODS = 5


def build_devices(cfg: DaemonConfig) -> DeviceSet:
    """Instantiate the configured backends (not started).

    :raises ConfigError: on unknown backends or invalid backend options.
    """
    from capstan.drivers import registry
    return DeviceSet(motor=registry.create("motor", cfg.motor), imu=registry.create("imu", cfg.imu),
                     load_cells=registry.create("load_cells", cfg.load_cells))


def build_controller(cfg: DaemonConfig) -> Any:
    """The Numba controller from the ``controller`` section (compiled, not yet warmed),
    after the loop's stability check (:func:`capstan.controller.law.stability.check_margins`).

    :raises ConfigError: on an invalid controller section, or gains that miss the required
        margins with the I/O delay (unless ``lab_override.margins``).
    """
    from capstan.controller.law.config import ControllerConfig
    from capstan.controller.law.core import Controller
    from capstan.controller.law.stability import check_margins
    ccfg = ControllerConfig.from_mapping(cfg.controller)
    rep = check_margins(ccfg, override=cfg.lab_override.margins)
    if not rep.ok:
        log.warning("lab override (%s): starting a torque loop outside its margins: %s",
                    cfg.lab_override.reason, rep.summary())
    else:
        log.info("torque loop margins: %s", rep.summary())
    for line in cfg.overridden:
        log.warning("lab override (%s): %s", cfg.lab_override.reason, line)
    return Controller(ccfg)


class Daemon:
    """One run of the control loop against a device set.

    :param cfg: validated configuration.
    :param devices: devices to drive (default: built from ``cfg`` through the registry).
    :param controller: object with ``record``, ``step()``, ``warmup()`` (default: built).
    :param sink: log sink (default: shared-memory ring + MCAP writer process).
    :param notifier: systemd notifier (default: from the environment).
    """

    def __init__(self, cfg: DaemonConfig, *, devices: DeviceSet | None = None, controller: Any = None,
                 sink: LogSink | None = None, notifier: SdNotifier | None = None) -> None:
        self.cfg = cfg
        self.devices = devices
        self.controller = controller
        self.sink = sink
        self.notifier = notifier if notifier is not None else SdNotifier()
        self.phase = Phase.STOPPED
        self.summary = RunSummary()
        self._stop = False
        self._log_started_s = 0.0
        self._looped = False          # the loop reached its first cycle (else the log is removed)

    def request_stop(self) -> None:
        """Ask the loop to ramp down and stop (async-signal safe: sets a flag)."""
        self._stop = True

    def _on_signal(self, signum: int, frame: Any) -> None:
        self._stop = True

    def run(self, duration_s: float | None = None) -> RunSummary:
        """Build, start and run the loop until a stop request, ``duration_s`` of control (counted
        from arming) or a fault.

        :raises ControlFaultError: a fault was latched (drive disabled, report logged).
        :raises DriverError: a device failed to start (e.g. DeviceTimeoutError at arming).
        :raises RealtimeError: in ``realtime: enforce`` mode without the privileges.
        :raises ConfigError: on invalid controller or device configuration.
        """
        ctl = self.controller if self.controller is not None else build_controller(self.cfg)
        ctl.warmup()
        shared_abs_sleep()                      # compile the loop's sleeper before any device starts
        self.controller = ctl
        if self.devices is None:
            self.devices = build_devices(self.cfg)
        self._log_started_s = time.time()
        self._looped = False
        if self.sink is None:
            lg = self.cfg.logging
            self.sink = open_session(lg.dir, ctl.record.dtype, logged_config(self.cfg.raw, ctl), lg.ring_records,
                                     lg.fault_history_cycles, wire=wire_capable(self.devices),
                                     imu_rate_float32=bool(getattr(self.devices.imu, "rate_is_float32", False)),
                                     on_writer_loss=lg.on_writer_loss, max_writer_restarts=lg.max_writer_restarts,
                                     rotate_size_MB=lg.rotate_size_MB, rotate_age_s=lg.rotate_age_s,
                                     keep_newest_GB=lg.keep_newest_GB)
        old_handlers = self._install_signals()
        dev = self.devices
        rt = None
        try:
            t0 = time.monotonic()
            rt = realtime.prepare(self.cfg.realtime)
            loop_cpus = set(self.cfg.realtime.cpus) if self.cfg.realtime.mode != realtime.RealtimeMode.OFF else set()
            if loop_cpus and hasattr(self.sink, "keep_writer_on"):   # the writer off the loop's CPUs
                self.sink.keep_writer_on(frozenset(set(range(os.cpu_count() or 1)) - loop_cpus))
            t1 = time.monotonic()
            dev.imu.start()
            dev.load_cells.start()
            dev.motor.start()
            send_derivations(self.sink, dev)
            t2 = time.monotonic()
            helpers = [t for t in threading.enumerate() if t is not threading.current_thread()]
            raised = realtime.apply_to_threads(self.cfg.realtime, rt, helpers)
            realtime.apply(self.cfg.realtime, rt)
            if raised:
                log.info("helper threads at SCHED_FIFO %d: %s", self.cfg.realtime.helper_priority,
                         ", ".join(raised))
            log.info("memory locked in %.3f s, devices started and drive enabled in %.3f s", t1 - t0, t2 - t1)
            self.summary.threads = [t.name for t in threading.enumerate()]
            if len(self.summary.threads) > 1:
                log.info("threads in the loop's process: %s", ", ".join(self.summary.threads))
            self._loop(ctl, dev, self.sink, None if duration_s is None else int(duration_s * 1e9))
        finally:
            if rt is not None:
                realtime.restore(rt)
                realtime.drop_to_normal_scheduling()
            self._shutdown(dev)
            self._restore_signals(old_handlers)
        return self.summary

    # ------------------------------------------------------------------ the loop
    def _loop(self, ctl: Any, dev: DeviceSet, sink: LogSink, duration_ns: int | None) -> None:
        L = self.cfg.loop
        lim = L.limits
        motor, imu, cells, note = dev.motor, dev.imu, dev.load_cells, self.notifier
        rec = ctl.record
        r = rec[0]
        n_hist = self.cfg.logging.fault_history_cycles
        hist = np.zeros(n_hist, dtype=rec.dtype)
        stats_buf = np.zeros(1, dtype=STATS_DTYPE)
        links = device_links(dev)
        writer_ok = True
        writer_lost = False
        sl = DeadlineSleeper(L.period_s, L.busy_tail_s)
        stats = LoopStats(L.period_s, max(1, round(L.stats_interval_s / L.period_s)))
        self._cq = cq = CommandQuality(max(1, round(L.stats_interval_s / L.period_s)), L.period_s,
                                       rate_step_Nm(self.cfg, L.period_s))
        ping = note.ping_interval_s
        ping_ns = int(ping * 1e9) if ping else 0
        last_ping = 0
        n_ramp = max(1, round(L.ramp_down_s / L.period_s))
        ramp_left = n_ramp
        fresh_s = L.sensor_fresh_s
        streak_fault = L.overrun_streak_fault
        phase = Phase.ARMING
        self.phase = phase
        end_ns: int | None = None
        arm_cycles = L.arm_on_time_cycles
        on_time = best_on_time = 0
        arm_until_ns = time.monotonic_ns() + int(L.startup_timeout_s * 1e9)
        imu_t = lc_t = m_t = -math.inf
        cpu0, wall0 = cpu_snapshot(sink), time.monotonic()
        reason = ""
        cycle = 0
        prev_wake = sl.start() - sl.period_ns
        dl = sl.deadline_ns
        wake, late = sl.wait()
        self._looped = True
        while True:
            t_s = wake * 1e-9
            ext = 0
            # ---- read: drain every device without blocking
            try:
                m = motor.poll()
            except HeartbeatLostError as exc:
                m, ext, reason = None, ext | FaultBits.HEARTBEAT_LOST, f"drive heartbeat lost: {exc}"
            except DriverError as exc:
                m, ext, reason = None, ext | FaultBits.DRIVE_FAULT, f"drive fault: {exc}"
            if m is not None:
                r["q_m_rad"] = m.position_rad
                r["dq_m_rad_s"] = m.velocity_rad_s
                r["tau_m_meas_Nm"] = m.torque_Nm
                r["motor_t_s"] = m_t = m.t_s
                r["q_m_counts"], r["dq_m_units"] = m.position_counts, m.velocity_units
                r["tau_m_meas_permille"], r["motor_t_ns"] = m.torque_permille, m.t_ns
            s = imu.poll()
            if s is not None:
                r["q_out_rad"] = s.q_out_rad
                r["dq_out_rad_s"] = s.dq_out_rad_s
                r["imu_t_s"] = imu_t = s.t_s
                r["imu_rate_rad_s"], r["imu_t_ns"] = s.rate_rad_s, s.t_ns
                r["imu_new"] = 1
            else:
                r["imu_new"] = 0
            c = cells.poll()
            if c is not None:
                T = c.tensions_N
                r["T_up_in_N"], r["T_up_out_N"], r["T_lo_out_N"], r["T_lo_in_N"] = T[0], T[1], T[2], T[3]
                r["lc_t_s"] = lc_t = c.t_s
                W = c.raw_mV_V
                r["lc_up_in_mV_V"], r["lc_up_out_mV_V"], r["lc_lo_out_mV_V"], r["lc_lo_in_mV_V"] = W[0], W[1], W[2], W[3]
                r["lc_t_ns"] = c.t_ns
            r["cycle"] = cycle
            r["t_s"] = t_s
            r["t_ns"] = wake
            if phase != Phase.ARMING and sl.streak >= streak_fault:
                ext |= FaultBits.OVERRUN_STREAK
                reason = reason or f"{sl.streak} consecutive late cycles (limit {streak_fault})"
            if phase != Phase.ARMING:
                v = limit_violation(r, lim)
                if v:
                    ext |= LIMIT_VIOLATION
                    reason = reason or v
                if self._stop and phase == Phase.RUNNING:
                    phase = self.phase = Phase.RAMPING
                    note.stopping("ramping torque to zero")
                    log.info("stop requested: ramping torque to zero over %.3f s", L.ramp_down_s)
            r["ext_fault_bits"] = ext
            # ---- step (gated by the phase; the gating is logged so a replay can follow it)
            r["phase"] = min(int(phase), int(Phase.RAMPING))
            if phase == Phase.ARMING:
                r["cmd_scale"] = scale = 0.0
                tau = 0.0
                fresh = all_fresh(t_s, fresh_s, m_t, imu_t, lc_t)
                on_time = on_time + 1 if (fresh and not late and ext == 0) else 0
                best_on_time = max(best_on_time, on_time)
                if on_time >= arm_cycles:
                    phase = self.phase = Phase.RUNNING
                    if duration_ns is not None:          # the duration is of control: it starts now
                        end_ns = wake + duration_ns
                    cpu0, wall0 = cpu_snapshot(sink), time.monotonic()
                    note.ready("drive enabled, sensors healthy, loop on time")
                    log.info("armed after %d cycles: drive enabled, sensors healthy, %d cycles on time",
                             cycle, on_time)
                elif ext == 0 and wake > arm_until_ns:
                    motor.write_torque(0.0)
                    motor.send_cycle()
                    missing = [n for n, t in (("drive", m_t), ("imu", imu_t), ("load_cells", lc_t))
                               if not t_s - t <= fresh_s]
                    if missing:
                        raise DeviceTimeoutError(f"no fresh data from {', '.join(missing)} within "
                                                 f"{L.startup_timeout_s} s after enable")
                    raise DeviceTimeoutError(
                        f"the loop did not hold its {L.period_s * 1e3:g} ms period within {L.startup_timeout_s} s "
                        f"after enable: longest run {best_on_time} on-time cycles, {sl.overruns} late "
                        f"(loop.arm_on_time_cycles {arm_cycles}); the host is too busy to run the loop")
            else:
                scale = 1.0
                if phase == Phase.RAMPING:
                    ramp_left -= 1
                    scale = max(ramp_left, 0) / n_ramp
                r["cmd_scale"] = scale
                tau = ctl.step()
            fault = int(r["fault_bits"]) | ext
            if not fault and not math.isfinite(tau * scale):
                fault, reason = int(FaultBits.NONFINITE_OUTPUT), "non-finite torque command"
            tau = loop_command(tau, scale, fault)
            r["tau_m_cmd_Nm"] = tau
            if r["phase"] == Phase.RUNNING:        # stepped and unscaled this cycle
                cq.add(tau, float(r["tau_in_Nm"]))
            else:
                cq.break_sequence()
            # ---- write: RPDO then SYNC
            motor.write_torque(tau)
            motor.send_cycle()
            done = time.monotonic_ns()
            r["period_s"] = (wake - prev_wake) * 1e-9
            r["compute_s"] = (done - wake) * 1e-9
            r["late"] = late
            sink.push(rec)
            hist[cycle % n_hist] = r
            stats.add((wake - prev_wake) * 1e-9, (wake - dl) * 1e-9, (done - wake) * 1e-9, late,
                      sl.gil_wait_ns * 1e-9)
            cycle += 1
            self.summary.cycles = cycle
            if fault:
                self._finish_summary(sl, stats, sink, cpu0, wall0)
                self._fault(motor, sink, hist, cycle, fault, reason or fault_names(fault), t_s,
                            float(r["period_s"]))
            if phase == Phase.RAMPING and ramp_left <= 0:
                break
            if end_ns is not None and wake >= end_ns:
                self._stop = True
            if stats.window_full:
                rep = stats.take_window()
                crep = cq.take_window()
                fill_stats(stats_buf, t_s, rep, sl.missed, sink.dropped, crep)
                stats_buf["drive_limit_total"] = getattr(motor, "internal_limit_cycles", 0)
                fill_link_stats(stats_buf, links)
                sink.push_stats(stats_buf)
                line = f"{Phase(phase).name.lower()}: " + rep.status_line()
                if crep.cycles:
                    line += (f", cmd std {crep.cmd_std_Nm * 1e3:.2f} mNm, change {crep.cmd_change_rms_Nm * 1e3:.3f} mNm/cycle, "
                             f">20 Hz {100 * crep.cmd_hf_share:.0f} %, rate hits {crep.rate_limit_hits}")
                if links:
                    line += "; links " + link_status(links)
                log.info("%s", line)
                note.status(line)
                if writer_is_lost(sink) and not writer_lost:
                    writer_lost = self._stop = True
                    log.error("log writer lost (logging.on_writer_loss: %s); ramping torque to zero",
                              self.cfg.logging.on_writer_loss)
                if not writer_ok and sink.writer_alive():
                    writer_ok = True
                elif writer_ok and not sink.writer_alive():
                    writer_ok = False
                    log.error("the log writer process is gone; cycle records are being dropped")
            if ping_ns and wake - last_ping >= ping_ns and sl.streak == 0:
                note.watchdog()
                last_ping = wake
            prev_wake = wake
            dl = sl.deadline_ns
            wake, late = sl.wait()
        self.phase = Phase.STOPPED
        self._finish_summary(sl, stats, sink, cpu0, wall0)
        if writer_lost:
            text = f"log writer lost: {getattr(sink, 'lost_reason', 'not restarted')}; torque ramped to zero"
            self.summary.faults.append(text)
            raise ControlFaultError(text, None)

    def _fault(self, motor: Any, sink: LogSink, hist: np.ndarray, cycles: int, bits: int,
               reason: str, t_s: float, gap_s: float) -> None:
        """Torque is already zero this cycle: disable the drive, report, raise.

        ``gap_s`` is the loop's own wake-to-wake interval ending at this cycle [s]: when it
        exceeds :data:`STALL_PERIODS` periods the reason says so — stale sensors and a lost
        heartbeat after such a gap mean the process got no CPU, not that a device went quiet.
        """
        self.phase = Phase.FAULTED
        lost = ""
        try:
            motor.disable()
        except DeviceLostError as exc:   # no heartbeat during one whole heartbeat timeout of trying
            bits, lost = bits | FaultBits.DEVICE_LOST, str(exc)
        except DriverError as exc:
            log.error("disabling the drive after the fault failed: %s", exc)
        n = min(cycles, len(hist))
        last = np.roll(hist, -(cycles % len(hist)))[-n:] if cycles >= len(hist) else hist[:n].copy()
        text = f"{fault_names(bits)}: {reason}"
        if lost and lost not in reason:
            text += f"; device loss: {lost}"
        self.summary.fault_gap_s = gap_s
        if gap_s > STALL_PERIODS * self.cfg.loop.period_s:
            text += (f"; the loop itself had not run for {gap_s * 1e3:.1f} ms before this cycle "
                     f"(host stall: the process got no CPU)")
        self.summary.faults.append(text)
        sink.fault(t_s, text, code=bits, n_cycles=len(hist))
        log.error("FAULT at t=%.3f s: %s (drive disabled; last %d cycles logged)", t_s, text, n)
        self.notifier.status("FAULT " + text)
        raise ControlFaultError(text, last, bits=bits)

    def _finish_summary(self, sl: DeadlineSleeper, stats: LoopStats, sink: LogSink,
                        cpu0: dict[str, float], wall0: float) -> None:
        cpu1 = cpu_snapshot(sink)
        self.summary.cpu_s = {k: cpu1[k] - cpu0[k] for k in cpu1 if k in cpu0}
        self.summary.loop_wall_s = time.monotonic() - wall0
        self.summary.missed = sl.missed
        self.summary.links = link_summary(device_links(self.devices))
        self.summary.overruns = sl.overruns
        self.summary.timing = stats.run_summary()
        self.summary.phase = self.phase.name
        cq = getattr(self, "_cq", None)
        if cq is not None:
            cq.take_window()
            self.summary.command = cq.run_report().to_dict()

    # ------------------------------------------------------------------ shutdown
    def _shutdown(self, dev: DeviceSet) -> None:
        self.notifier.stopping("shutting down")
        for name, action in (("drive disable", dev.motor.disable), ("drive close", dev.motor.close),
                             ("imu close", dev.imu.close), ("load cells close", dev.load_cells.close)):
            try:
                action()
            except Exception as exc:  # noqa: BLE001 - every step of shutdown must run
                log.error("%s failed: %s", name, exc)
        if self.sink is not None:
            self.summary.dropped_log_records = self.sink.dropped
            self.sink.close()
            out_dir = getattr(self.sink, "out_dir", None)
            if out_dir is not None:
                path = newest_log(out_dir, since_s=self._log_started_s - 1.0)
                if path is not None and not self._looped:
                    # a start that failed before the first cycle: nothing to keep, and under
                    # systemd one empty file per restart would pile up
                    path.unlink(missing_ok=True)
                    log.info("no cycle ran: removed the log %s", path)
                    path = None
                self.summary.log_path = None if path is None else str(path)
        self.summary.phase = self.phase.name

    def _install_signals(self) -> dict[int, Any]:
        if threading.current_thread() is not threading.main_thread():
            return {}
        old = {}
        for sig in (signal.SIGTERM, signal.SIGINT):
            old[sig] = signal.signal(sig, self._on_signal)
        return old

    @staticmethod
    def _restore_signals(old: dict[int, Any]) -> None:
        for sig, handler in old.items():
            signal.signal(sig, handler)
