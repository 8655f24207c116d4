"""omnican on ROS 2, without a ROS installation: a DDS bridge (Cyclone DDS) that speaks
ROS 2's topics and types, for ``omnican ros2`` (``pip install 'omnican[ros2]'``).

``settings`` and ``model`` are pure; ``msgs`` declares the ROS 2 message types for
Cyclone DDS; ``bridge`` connects a running Chassis to DDS.
"""
