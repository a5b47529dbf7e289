"""PMSM plant core: continuous-time motor, averaged inverter and current sensing (no rclpy), and the
plant node."""
