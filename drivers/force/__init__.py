"""Force/torque sensors: the simulated one and (issue 6) ATI Net F/T."""
