"""The one-process runner: the cores composed in one compiled loop, directly or through the inverter
bridge."""
