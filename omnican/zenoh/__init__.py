"""The base on Zenoh, in rmw_zenoh's format (the ``[zenoh]`` extra): :mod:`.rmw` is the
wire format (pure), :mod:`.bridge` the front end that publishes the telemetry and takes
cmd_vel, :mod:`.session` opens Zenoh sessions as the settings say."""
