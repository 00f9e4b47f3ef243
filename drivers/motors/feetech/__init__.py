"""Feetech SCS/STS servos: the bus protocol (``protocol``) and one bus (``bus``)."""
