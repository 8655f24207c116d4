"""Pure CANopen and CAN (no I/O): CiA 301 and 402 tables, heartbeat timing, the
expedited SDO cycle, the CAN controller's state, EDS checks, where a drive keeps
each object; and the codec of another base's protocol (SLAMWARE)."""
