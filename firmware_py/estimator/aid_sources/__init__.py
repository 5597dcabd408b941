"""One module per aid source (accelerometer, magnetometer, barometer, tether), as PX4 EKF2's aid
sources: each keeps its control (when to fuse, what to reset) beside its fusion (the rows), and each
fusion keeps a ``FusionStatus`` (innovation, its variance, test ratio, fused and rejected counts, time of
the last fusion)."""
