"""The bridge to a real inverter and nothing else (no rclpy but the node): the wire protocol, serial and CAN
links, the host bridge core and the drive_bridge node. The virtual inverter that stands in for a real one is a
test double (drive_tools.doubles)."""
