"""The :class:`capstan.drivers.interfaces.LoadCells` for the 4-channel serial amplifier (pyserial).

Frame format: :mod:`capstan.drivers.serial.loadcell_protocol`. Per channel ``T_N = scale_N_per_mV_V *
raw_mV_V + offset_N - tare_N``, channels in the order upper input-side, upper
output-side, lower output-side, lower input-side. ``poll()`` never blocks: it reads the
available bytes, parses every complete frame (counting good/bad frames and resyncs
in ``stats``) and returns the newest sample.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any, Mapping

from capstan.drivers.interfaces import LinkStats, LoadCellSample
from capstan.drivers.serial.loadcell_protocol import FRAME_LEN, N_CHANNELS, LoadCellParser
from capstan.drivers.serial.port_io import port_fd, read_available
from capstan.models.common.config_tools import get_float, get_int, reject_unknown
from capstan.models.common.errors import ConfigError, DeviceTimeoutError, DriverError
from capstan.models.common.wire_units import NS_TO_S, Derivation, seconds_from_ns, tension_ops

log = logging.getLogger(__name__)

FRAME_RATE_HZ = 1000
_KEYS = frozenset({"port", "baudrate", "scale_N_per_mV_V", "offset_N", "tare_N", "tare_samples",
                   "timeout_s"})


def _four_floats(cfg: Mapping[str, Any], key: str, prefix: str, default: float) -> tuple[float, ...]:
    path = f"{prefix}.{key}"
    val = cfg.get(key)
    if val is None:
        return (default,) * N_CHANNELS
    if not isinstance(val, (list, tuple)) or len(val) != N_CHANNELS:
        raise ConfigError(path, f"must be a list of {N_CHANNELS} numbers "
                                f"(upper in, upper out, lower out, lower in), got {val!r}")
    return tuple(get_float({key: v}, key, prefix) for v in val)


@dataclass(frozen=True)
class LoadCellConfig:
    """Amplifier settings (section ``load_cells`` of ``config/serial_devices.yaml``).

    :ivar port: serial device path.
    :ivar baudrate: line rate [Bd]; at least 10 bits x 19 bytes x 1000 frames/s.
    :ivar scale_N_per_mV_V: per-channel sensitivity [N per mV/V].
    :ivar offset_N: per-channel offset added after scaling [N].
    :ivar tare_N: per-channel tare subtracted [N] (replaced when ``tare_samples`` > 0).
    :ivar tare_samples: frames averaged at ``start()`` to set the tare (0 = keep ``tare_N``).
    :ivar timeout_s: wait for the first frames at start [s].
    """

    port: str
    baudrate: int = 460800
    scale_N_per_mV_V: tuple[float, ...] = (250.0,) * N_CHANNELS
    offset_N: tuple[float, ...] = (0.0,) * N_CHANNELS
    tare_N: tuple[float, ...] = (0.0,) * N_CHANNELS
    tare_samples: int = 0
    timeout_s: float = 1.0

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any], prefix: str = "load_cells") -> LoadCellConfig:
        """Validate a mapping (e.g. the ``load_cells`` section).

        :raises ConfigError: naming the key and the reason.
        """
        reject_unknown(cfg, _KEYS, prefix)
        if not isinstance(cfg.get("port"), str) or not cfg["port"]:
            raise ConfigError(f"{prefix}.port", "missing serial device path (string)")
        scale = _four_floats(cfg, "scale_N_per_mV_V", prefix, 250.0)
        if any(s == 0.0 for s in scale):
            raise ConfigError(f"{prefix}.scale_N_per_mV_V", f"must be non-zero, got {list(scale)}")
        baud = get_int(cfg, "baudrate", prefix, default=460800, min_value=9600)
        need = 10 * FRAME_LEN * FRAME_RATE_HZ
        if baud < need:
            raise ConfigError(f"{prefix}.baudrate", f"{baud} Bd cannot carry {FRAME_RATE_HZ} frames/s "
                                                    f"of {FRAME_LEN} bytes (needs >= {need})")
        return cls(port=cfg["port"], baudrate=baud, scale_N_per_mV_V=scale,
                   offset_N=_four_floats(cfg, "offset_N", prefix, 0.0),
                   tare_N=_four_floats(cfg, "tare_N", prefix, 0.0),
                   tare_samples=get_int(cfg, "tare_samples", prefix, default=0, min_value=0),
                   timeout_s=get_float(cfg, "timeout_s", prefix, default=1.0, min_value=0.0,
                                       min_exclusive=True))


class SerialLoadCells:
    """The amplifier over pyserial; implements :class:`capstan.drivers.interfaces.LoadCells`.

    :param config: validated settings.
    :param port: an already open pyserial port; if None, ``start()`` opens ``config.port``.
    """

    def __init__(self, config: LoadCellConfig, port: Any = None) -> None:
        self.config = config
        self.stats = LinkStats()
        self.tare_N = tuple(config.tare_N)
        self.last_raw_mV_V: tuple[float, float, float, float] | None = None
        self._port = port
        self._fd = -1
        self._parser = LoadCellParser(self.stats)

    @classmethod
    def from_config(cls, cfg: Mapping[str, Any], prefix: str = "load_cells") -> SerialLoadCells:
        """Build from the ``load_cells`` config section.

        :raises ConfigError: on an invalid section.
        """
        return cls(LoadCellConfig.from_mapping(cfg, prefix))

    def to_tensions_N(self, raw_mV_V: tuple[float, ...]) -> tuple[float, float, float, float]:
        """Apply scale, offset and tare to one frame [mV/V] -> tensions [N]."""
        s, o, t = self.config.scale_N_per_mV_V, self.config.offset_N, self.tare_N
        return (s[0] * raw_mV_V[0] + o[0] - t[0], s[1] * raw_mV_V[1] + o[1] - t[1],
                s[2] * raw_mV_V[2] + o[2] - t[2], s[3] * raw_mV_V[3] + o[3] - t[3])

    def derivations(self) -> list[Derivation]:
        """How a log rebuilds the tensions from the logged bridge signals: exactly
        :meth:`to_tensions_N` (valid after :meth:`start`, which may tare)."""
        s, o, t = self.config.scale_N_per_mV_V, self.config.offset_N, self.tare_N
        names = (("T_up_in_N", "lc_up_in_mV_V"), ("T_up_out_N", "lc_up_out_mV_V"),
                 ("T_lo_out_N", "lc_lo_out_mV_V"), ("T_lo_in_N", "lc_lo_in_mV_V"))
        return [Derivation(f, src, tension_ops(s[k], o[k], t[k])) for k, (f, src) in enumerate(names)] \
            + [Derivation("lc_t_s", "lc_t_ns", NS_TO_S)]

    def start(self) -> None:
        """Open the port, wait for the stream, tare if configured (blocks up to ``timeout_s``).

        :raises DriverError: if the port cannot be opened.
        :raises DeviceTimeoutError: if no (or too few, for the tare) valid frames arrive.
        """
        if self._port is None:
            import serial  # lazy: only the real backend needs it

            try:
                self._port = serial.Serial(self.config.port, self.config.baudrate, timeout=0)
            except (serial.SerialException, OSError) as exc:
                raise DriverError(f"cannot open load-cell port {self.config.port}: {exc}") from exc
        need = max(1, self.config.tare_samples)
        try:
            frames = self._first_frames(need)
        except OSError as exc:  # serial.SerialException derives from OSError
            raise DriverError(f"load-cell port {self.config.port} failed during start-up: {exc}") from exc
        if self.config.tare_samples:
            frames = frames[:need]
            s, o = self.config.scale_N_per_mV_V, self.config.offset_N
            self.tare_N = tuple(sum(s[k] * f[k] + o[k] for f in frames) / len(frames)
                                for k in range(N_CHANNELS))
            log.info("load cells tared over %d frames: %s N", len(frames),
                     ", ".join(f"{t:.2f}" for t in self.tare_N))
        self.last_raw_mV_V = frames[-1]  # type: ignore[assignment]
        log.info("load cells on %s streaming at %d Bd", self.config.port, self.config.baudrate)

    def _first_frames(self, need: int) -> list[tuple[float, ...]]:
        self._port.timeout = 0
        self._fd = port_fd(self._port)
        self._port.reset_input_buffer()
        self._parser.reset()
        frames: list[tuple[float, ...]] = []
        deadline = time.monotonic() + self.config.timeout_s
        while len(frames) < need:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeoutError(f"load cells on {self.config.port}: {len(frames)} of {need} "
                                         f"valid frames within {self.config.timeout_s} s")
            self._port.timeout = min(remaining, 0.05)
            chunk = self._port.read(max(1, self._port.in_waiting))
            self._port.timeout = 0
            frames += self._parser.feed(chunk)
        return frames

    def poll(self) -> LoadCellSample | None:
        """Read available bytes without blocking; the newest sample, or None.

        :raises DriverError: if the port fails (device unplugged).
        """
        try:
            data = read_available(self._port, self._fd)
        except OSError as exc:  # serial.SerialException derives from OSError
            raise DriverError(f"load-cell port {self.config.port} failed: {exc}") from exc
        if not data:
            return None
        frames = self._parser.feed(data)
        if not frames:
            return None
        raw = frames[-1]
        self.last_raw_mV_V = raw
        t_ns = time.monotonic_ns()
        return LoadCellSample(t_s=seconds_from_ns(t_ns), tensions_N=self.to_tensions_N(raw),
                              t_ns=t_ns, raw_mV_V=raw)

    def close(self) -> None:
        """Close the port (idempotent)."""
        if self._port is not None:
            self._port.close()
            self._port = None
            self._fd = -1
