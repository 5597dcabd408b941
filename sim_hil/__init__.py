"""balloon-wind HIL simulator: Van der Hoven wind, 6-DOF tethered balloon, sensors, MAVLink packets."""
