"""Calibration (paper section IV, Algorithm 1): camera-to-robot transform and actuator inputs."""
