"""Stereo cameras: the simulated pair and OpenCV devices."""
