"""Safety paths across separate processes (the simulator in one, the host in another)."""
