"""Pure robot maths (numpy only, no I/O): kinematics, odometry, limits, the
encoder fold, the wheel checks (tracking, lift)."""
