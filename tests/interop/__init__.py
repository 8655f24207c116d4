"""Against other programs: real ROS 2, Foxglove's own packages and app, the kernel's SocketCAN, the dependency floors."""
