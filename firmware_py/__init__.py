"""balloon-wind firmware: fixed-step, allocation-free EKF turning raw IMU/baro packets into WIND_COV."""
