"""What the drive's packages share (no node, no rclpy but ``contract.node``): the motor and its inverter
(``motor``), configuration and scenarios (``config``), the contract between nodes, bags and users and its records
(``contract``, docs/drive-interface.md), the numba kernels of control (``math``) and the process's run time
(``runtime``: signals, scheduling, the machine's load)."""
