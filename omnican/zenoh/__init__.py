"""The base on Zenoh, in rmw_zenoh's format (the ``[zenoh]`` extra): :mod:`.rmw` is the
wire format (pure), :mod:`.settings` what the front end is told, :mod:`.bridge` the
front end that publishes the telemetry and takes cmd_vel, :mod:`.services` the base's
stop, recover and reset_odometry services."""
