"""Display units of the paper, as factors to SI (the code is SI inside)."""

MPA = 1e6  # Pa per MPa
MM = 1e-3  # m per mm

STANDARD_GRAVITY = 9.80665  # m/s^2, ISO 80000-3
