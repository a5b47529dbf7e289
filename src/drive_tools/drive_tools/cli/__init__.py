"""The `drive` command line."""
