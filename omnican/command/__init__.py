"""What front ends share to command the base: the teleop and gamepad models, scripted
motion, and cmd_vel's intake from a network (the ROS 2 and Zenoh front ends'). One
source at a time is the base's own rule: a front end sends through the handle
:meth:`omnican.chassis.Chassis.command_source` gives it (:mod:`omnican.chassis.arbiter`)."""
