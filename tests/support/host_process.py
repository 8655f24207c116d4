"""A host program for the process-level safety tests: opens the base from a config
(recording the bus to argv[2] if given), says "ready", and keeps commanding forward
motion until it is signalled."""

from __future__ import annotations

import sys
import time

from omnican import Chassis, load_config
from omnican.record.recording import FileRecording


def main() -> int:
    cfg = load_config(sys.argv[1])
    record = FileRecording(sys.argv[2]) if len(sys.argv) > 2 else None
    try:
        with Chassis.open(cfg, record=record) as base:
            print("ready", flush=True)
            while True:
                base.set_velocity(0.3, 0.0, 0.0)
                time.sleep(0.02)
    except KeyboardInterrupt:
        print("interrupted", flush=True)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
