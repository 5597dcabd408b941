"""``balloon-gs web`` under test: the server runner, the feed and the browser from tools/web_feed.py; a small
synthetic product (and its profile) to show."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from tools.web_feed import (  # noqa: F401 - re-exported for the tests
    CHROMIUM,
    PY,
    WebServer,
    free_tcp_port,
    free_udp_port,
    have_browser,
    launch_chromium,
    wait_until,
)


def write_product(path: Path) -> Path:
    """A synthetic 20-minute product at 10 Hz with one winch leg up and one down (and its ``_profile.nc``)."""
    from postflight.netcdf import write_netcdf
    from postflight.product import WindProduct
    from postflight.profile import wind_profile, write_profile

    t = np.arange(12000) / 10.0
    leg = 300.0
    phase = (t % (2 * leg)) / leg
    reel = np.where(phase < 1.0, 0.5, -0.5)
    length = 0.5 * leg * np.where(phase < 1.0, phase, 2.0 - phase) + 5.0
    h = length * 0.9
    speed = 3.0 + 0.02 * h + 0.3 * np.sin(t / 20.0)
    frm = 250.0 + 0.1 * h
    n, e = -speed * np.cos(np.radians(frm)), -speed * np.sin(np.radians(frm))
    z = np.zeros_like(t)
    p = WindProduct(time_s=t, wind_n=n, wind_e=e, sigma_n=z + 0.2, sigma_e=z + 0.2, causal_n=n + 0.1,
                    causal_e=e - 0.1, causal_sigma_n=z + 0.35, causal_sigma_e=z + 0.35, height_m=h, pos_n=z, pos_e=z,
                    air_pressure_pa=z + 101000.0, air_temperature_k=z + 288.0, mode=np.full(t.size, 2, np.int8),
                    flags=np.ones(t.size, np.int8), line_length_m=length, reel_mps=reel)  # fmt: skip
    write_netcdf(p, str(path))
    prof = wind_profile(p)
    assert prof is not None and len(prof.legs) >= 2
    write_profile(prof, p, str(path.with_name(path.stem + "_profile.nc")))
    return path


def math_close_deg(a: float, b: float, tol: float) -> bool:
    return abs((a - b + 180.0) % 360.0 - 180.0) <= tol + 1e-9 and math.isfinite(a)
