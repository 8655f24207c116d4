"""A host program with an IMU, for the process-level fusion tests: opens the base from a
config (argv[1]), attaches an IMU inbox the lines of its stdin feed (one yaw rate in
rad/s a line, stamped on arrival: a gyro in another process), says "ready", keeps
commanding forward motion, and prints each new stop reason ("stopped: ...") and warning
("warning: ...") until it is signalled."""

from __future__ import annotations

import sys
import threading
import time

from omnican import Chassis, load_config
from omnican.core.imu import ImuInbox, ImuSample


def feed(inbox: ImuInbox) -> None:
    for line in sys.stdin:
        try:
            rate = float(line)
        except ValueError:
            continue
        inbox.put(ImuSample(time.monotonic(), rate))


def main() -> int:
    cfg = load_config(sys.argv[1])
    try:
        with Chassis.open(cfg) as base:
            inbox = ImuInbox()
            base._loop.imu = inbox  # what an [imu] source does when it attaches
            threading.Thread(target=feed, args=(inbox,), daemon=True).start()
            print("ready", flush=True)
            said: set[str] = set()
            while True:
                base.set_velocity(0.3, 0.0, 0.0)
                status = base.status
                for line in ([f"stopped: {status.stopped_reason}"]
                             if status.stopped_reason else []) + \
                        [f"warning: {w.split(':')[0]}" for w in status.warnings]:
                    if line not in said:
                        said.add(line)
                        print(line, flush=True)
                time.sleep(0.02)
    except KeyboardInterrupt:
        print("interrupted", flush=True)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
