"""What front ends share to command the base: the teleop and gamepad models, the
arbiter (one source at a time), scripted motion."""
