"""Camera identification and calibration (affine 4-point, DLT, ChArUco); issue 7."""
