"""Force/torque sensors: the simulated one and ATI Net F/T."""
