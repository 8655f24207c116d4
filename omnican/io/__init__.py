"""The only owners of sockets and of python-can's Notifier: the bus, canopen's network
for a shared bus, the lock-step bus, the loopback hub."""
