"""Devices produce frames (depth camera) and samples (IMU).

One base class per device kind, a registry by name, real backends imported lazily,
mock backends that speak the real protocol over the real transport.
"""
