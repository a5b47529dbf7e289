"""The drive interface contract (docs/drive-interface.md) as code: the topic table, the wire format, the log
layout, sample stamps, the estimator's records, exit codes, domain errors and the base classes of every node
(``node``, ``scenario_node``: the only modules that import rclpy)."""
