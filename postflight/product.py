"""What post-flight reprocessing produces, before it is written anywhere (NetCDF, CSV, plots).

All arrays share one time axis (the estimator's output grid, normally 10 Hz). NaN where a value is
unknown (before the filter started, no barometer in the log, ...)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from firmware_py.estimator.consistency import SOURCES

# bits of ``flags`` (CF flag_masks)
FLAG_SMOOTHED = 1  # the smoothed value differs from the causal one (the segment had later data)
FLAG_SEGMENT_START = 2  # first sample after a filter reset / re-placement (a smoother segment starts)
FLAG_NO_BARO = 4  # the log has no barometer: height and air data are unknown
FLAG_WIND_UNKNOWN = 8  # horizontal accuracy worse than the wind itself could be (not a balloon, on the ground)
FLAG_AFTER_GAP = 16  # IMU samples were missing since the estimate before (a hole in the log, a lost stretch)
# bits of ``consistency_flags``: the causal filter's consistency monitor (firmware_py/estimator/consistency.py),
# bit i = aid source SOURCES[i] whose windowed normalised innovation squared says the model does not explain it
CONSISTENCY_MASKS = tuple(1 << i for i in range(len(SOURCES)))
CONSISTENCY_MEANINGS = " ".join(f"{name}_misfit" for name in SOURCES)


@dataclass
class WindProduct:
    time_s: np.ndarray  # seconds since the sensor clock's zero (boot)
    wind_n: np.ndarray  # smoothed (zero-lag) air velocity, m/s North
    wind_e: np.ndarray  # m/s East
    sigma_n: np.ndarray  # 1-sigma of wind_n from the smoothed covariance, m/s
    sigma_e: np.ndarray
    causal_n: np.ndarray  # the real-time filter's estimate (what WIND_COV carried)
    causal_e: np.ndarray
    causal_sigma_n: np.ndarray
    causal_sigma_e: np.ndarray
    height_m: np.ndarray  # above the tether anchor (NaN without a barometer)
    pos_n: np.ndarray  # balloon position relative to the anchor, m
    pos_e: np.ndarray
    air_pressure_pa: np.ndarray  # NaN without a barometer
    air_temperature_k: np.ndarray
    mode: np.ndarray  # int8: 0 ground, 1 free ascent, 2 taut (firmware_py.estimator.state MODE_*)
    flags: np.ndarray  # int8 bit field, FLAG_* above
    # the causal filter's consistency monitor at each time (None: not known, e.g. a product built elsewhere):
    consistency_flags: np.ndarray | None = None  # int8 bit field, CONSISTENCY_MASKS (what SYS_STATUS said in flight)
    accuracy_inflation: np.ndarray | None = None  # its factor (>= 1) on the accuracy WIND_COV reported
    # the winch (None: the flight had none): the tether's paid-out length the filter used, m, and the reel's
    # speed, m/s (positive paying out); NaN before the first WINCH_STATUS
    line_length_m: np.ndarray | None = None
    reel_mps: np.ndarray | None = None
    # WINCH_STATUS records the estimator rejected as implausible since the estimate before (int32; None: not
    # known, the flight's count is then only the ``winch_status_rejected`` attribute)
    winch_rejected: np.ndarray | None = None
    # a log in segments (the sensor clock went back, a reboot, or jumped): each segment its own filter and
    # smoother run. ``segment`` numbers them from 0; ``time_since_boot_s`` is the sensor clock, and ``time_s``
    # then runs on: a segment whose clock starts before the previous one ended is shifted to follow it
    segment: np.ndarray | None = None  # int16, the segment of each estimate (None: one segment)
    time_since_boot_s: np.ndarray | None = None  # the sensor clock (None: the same as time_s)
    utc_start_s: float | None = None  # UNIX time of time_s == 0 when the log knows it (GPS time), else None
    attrs: dict[str, str] = field(default_factory=dict)  # design TOML, software version, source name, sha256
