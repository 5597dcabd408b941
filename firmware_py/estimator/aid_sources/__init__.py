"""One module per aid source, its control beside its fusion: accelerometer, magnetometer, barometer, tether."""
