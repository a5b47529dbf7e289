"""The drive as a ROS 2 graph: the launcher that composes or spawns the nodes, the scenario driver,
and `drive echo`."""
