"""The bridge to a real inverter (no rclpy but the node): the wire protocol, serial and CAN links, the host
bridge core, the drive_bridge node, and a virtual inverter (the plant behind the protocol) for tests."""
