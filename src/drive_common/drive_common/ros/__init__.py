"""The base classes of every node (the only modules of the library that import rclpy): fault counters,
/diagnostics, peer and foreign-publisher watches, one /clock, and a node configured by a scenario."""
