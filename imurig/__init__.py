"""imurig: a simulation-based test bench and virtual calibration rig for IMUs.

Flow: rig (MuJoCo) -> truth at the IMU -> sensor chain -> Recording -> calibration -> report.
Subpackages: imurig.rigs, imurig.sensors, imurig.calibration, imurig.campaigns.
"""
__version__ = "0.1.0"
