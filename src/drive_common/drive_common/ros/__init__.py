"""The base class of every node, DriveNode (the library's only module that imports rclpy): its drive
configuration or scenario from its parameters, fault counters, /diagnostics, peer and foreign-publisher
watches, one /clock."""
