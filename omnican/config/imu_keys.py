"""The keys of the ``[imu]`` table (an IMU whose yaw rate the base fuses with its
wheels', :mod:`omnican.core.fusion`: on the CAN bus through a DBC, :mod:`omnican.io.imu`,
or a ``sensor_msgs/Imu`` topic a front end reads) and of ``[sim.gyro]`` (the simulated
base's gyro, :mod:`omnican.sim.gyro`): part of :data:`omnican.config.schema.SCHEMA`,
which takes its defaults and ranges from here like any table's.

Pure data: no I/O.
"""

from __future__ import annotations

from omnican.config.key import NUMBER, Key
from omnican.layers import FRONT_ENDS

#: Values of imu.source: where an IMU's readings come from: the bus ("can"), or the
#: front ends that read a sensor_msgs/Imu topic (by their registry's names).
IMU_SOURCES = ("can", *(name for name, entry in FRONT_ENDS.items() if entry.imu_topic))

_WAIT = (0.01, 60.0)  # s, as the schema's other waits

#: The [imu] table. A silent IMU is a status warning, never a stop.
IMU_KEYS: dict[str, Key] = {
    "source": Key((str,), None, "where the IMU's readings come from: " + ", ".join(
        f'"{s}"' for s in IMU_SOURCES) + " (a sensor_msgs/Imu topic)", required=True),
    "dbc": Key((str,), None, "can: the DBC file describing the IMU's messages (relative to "
               "the config file); e.g. the bundled \"openimu300ri.dbc\""),
    "message": Key((str,), None, "can: the DBC message carrying the yaw rate (its name)"),
    "yaw_rate": Key((str,), None, "can: the signal of that message with the yaw rate (about "
                    "the IMU's z axis)"),
    "yaw_rate_unit": Key((str,), None, "can: \"deg/s\" or \"rad/s\"; default the DBC "
                         "signal's unit"),
    "accel_message": Key((str,), None, "can: the DBC message with the accelerations; default "
                         "the yaw rate's"),
    "accel_x": Key((str,), None, "can: the signal with the acceleration along the IMU's x "
                   "axis (optional)"),
    "accel_y": Key((str,), None, "can: the signal with the acceleration along the IMU's y "
                   "axis (optional)"),
    "accel_unit": Key((str,), None, "can: \"m/s^2\" or \"g\"; default the DBC signal's "
                      "unit"),
    "topic": Key((str,), "/imu/data", "ros2, zenoh: the sensor_msgs/Imu topic"),
    "mount_yaw_deg": Key(NUMBER, 0.0, "the IMU's x axis turned this far counter-clockwise of "
                         "the base's (turns its accelerations; the yaw rate stays)",
                         range=(-360.0, 360.0)),
    "upside_down": Key((bool,), False, "the IMU's z axis points down (mounted upside down, "
                       "or a z-down frame): its yaw rate and y axis are negated"),
    "stale_s": Key(NUMBER, 0.5, "no reading for this long: the IMU counts as silent (a "
                   "status warning; the base falls back to its wheels)", range=_WAIT),
}

#: The [sim.gyro] table: with a CAN [imu], `--sim` sends the true yaw rate through the
#: IMU's DBC message, as this gyro would measure it.
SIM_GYRO_KEYS: dict[str, Key] = {
    "enabled": Key((bool,), True, "send the gyro's readings (false: an IMU that stays "
                   "silent)"),
    "rate_hz": Key(NUMBER, 100.0, "how often the gyro's message is sent",
                   range=(1.0, 1000.0)),
    "bias_deg_s": Key(NUMBER, 0.0, "deg/s the gyro reads at rest (its bias at start)",
                      range=(-100.0, 100.0)),
    "drift_deg_s": Key(NUMBER, 0.0, "deg/s per square root of a second: how fast the bias "
                       "wanders (a random walk)", range=(0.0, 10.0)),
    "noise_deg_s": Key(NUMBER, 0.0, "deg/s: the white noise of each reading (standard "
                       "deviation)", range=(0.0, 100.0)),
    "mount_yaw_deg": Key(NUMBER, None, "how the simulated IMU really sits; default as [imu] "
                         "says", range=(-360.0, 360.0)),
    "noise_stream": Key((int,), 0, "which random noise and drift: the same number, the "
                        "same readings run after run", range=(0, 2**32 - 1)),
}
