"""The drive interface contract (docs/drive-interface.md) as code: the topic table, the log layout,
sample stamps, domain errors and the base class of every node (``node``, the only module that imports
rclpy)."""
