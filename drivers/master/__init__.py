"""Haptic master arms: a simulated one and a 3D Systems Touch, behind ``MasterArm``."""
