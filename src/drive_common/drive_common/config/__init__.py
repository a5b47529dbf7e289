"""Configuration apart from experiment, as types: DriveConfig (what a drive reads), Experiment (what a
simulation adds) and Scenario (the two), read through declared keys; the shipped scenarios, and where a
node's parameters came from."""
