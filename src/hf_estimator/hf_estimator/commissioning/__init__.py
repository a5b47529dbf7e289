"""Self-commissioning at standstill: the procedure that measures the drive's own motor, inverter and
current sensors through its samples (currents in, voltage commands out), and its ROS node."""
