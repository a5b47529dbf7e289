"""Names of the ROS graph a drive lives in (no rclpy): its default namespace, its nodes, the executors."""

DEFAULT_NAMESPACE = "/drive"
EXECUTORS = ("events", "single")
"""``events``: rclpy.experimental.EventsExecutor; ``single``: the SingleThreadedExecutor (fallback)."""
NODES = {"pmsm_plant": "pmsm_plant.node", "hf_estimator": "hf_estimator.node",
         "drive_commissioning": "hf_estimator.commissioning.node",
         "foc_controller": "foc_controller.node", "drive_bridge": "drive_bridge.bridge_node"}
"""Node name → the module whose ``main`` runs it as a process (``python -m MODULE``)."""
