"""A daemon stand-in for kill tests: start the CANopen motor, then command a torque every ms forever.

``python canopen_master_proc.py CHANNEL EDS TORQUE_NM [key=value ...]`` prints ``enabled`` once the
drive is in OPERATION ENABLED; it never stops by itself (the test kills it).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from cia402_helpers import make_motor  # noqa: E402


def main() -> None:
    channel, eds, torque = sys.argv[1], sys.argv[2], float(sys.argv[3])
    extra = dict(a.split("=", 1) for a in sys.argv[4:])
    cfg = {k: float(v) for k, v in extra.items()}
    motor, _bus = make_motor(channel, eds=eds, rated_torque_Nm=2.0, **cfg)
    motor.start()
    print("enabled", flush=True)
    while True:
        motor.write_torque(torque)
        motor.send_cycle()
        time.sleep(0.001)
        motor.poll()


if __name__ == "__main__":
    main()
