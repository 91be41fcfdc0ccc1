"""What a host talks to: the simulated worlds (plant and controller in one process, or each alone on
a CAN bus), the nodes they are built from, the in-process bus and the OS ports."""
