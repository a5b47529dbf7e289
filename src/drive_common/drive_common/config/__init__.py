"""Configuration: declared keys (types, units, bounds), the drive configuration and scenario files, the
shipped scenarios, and where a node's parameters came from."""
