"""Emulated self-calibrating IMU of digital closed-loop quartz flexible accelerometers."""

__version__ = '0.1.0'
