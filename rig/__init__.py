"""uwb-rig: hardware-in-the-loop test rig for an onboard UWB TDOA + IMU estimator."""

__version__ = "0.1.0"
