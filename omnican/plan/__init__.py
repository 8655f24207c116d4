"""This robot on the wire, worked out offline from the config and the EDS files: the
PDO plan, the compiled PDO codec, the health plan, the [[wheel.sdo]] writes, each node's
layout, the DBC."""
