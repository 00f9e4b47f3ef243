"""Camera identification and calibration (affine 4-point, DLT, ChArUco): docs/calibration.md."""
