"""An estimator plugin for the sensorless PMSM drive (docs/estimator-plugins.md of the drive's repository)."""
