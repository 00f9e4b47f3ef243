"""The SO-101 arm on Feetech STS3215 bus servos: the byte protocol (``feetech``), a bus
emulator that speaks it (``emulator``), the joint calibration (``calibration``) and the
driver (``arm``)."""
