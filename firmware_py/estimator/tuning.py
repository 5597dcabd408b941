"""Process noise of the wind, derived from the spectrum the filter expects (not hand-set).

The filter's wind is an integrated Ornstein-Uhlenbeck process, per horizontal axis:

    dw/dt = r,    dr/dt = -r / tau + nu,    nu white with (two-sided) intensity q_r

Its one-sided spectrum is S(f) = 2 q_r / (omega^2 (omega^2 + 1/tau^2)), omega = 2 pi f: a random walk
of intensity q_w = q_r tau^2 below 1/(2 pi tau), falling as f^-4 above. The expected wind is IEC
61400-1 Kaimal turbulence at the mean wind U, sigma_u = TI U, L = 340.2 m (8.1 x 42 m above 60 m):

    S_K(f) = 4 sigma_u^2 (L/U) / (1 + 6 f L/U)^(5/3) x sinc^2(f D / U)

the second factor being what a sphere of diameter D feels of it (the air is averaged over the body,
frozen turbulence). In the band that matters (``BAND_HZ``) the Kaimal spectrum falls as f^-5/3;
the random walk that matches it best in the least-squares sense on log S fixes q_w; the rate's time
constant is the time the air takes to cross the balloon, tau = D / U: faster changes are averaged
out over the sphere and do not push it as a whole.

Pure functions of plain floats, evaluated once at start (the filter's step only uses the result).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

KAIMAL_LENGTH_M = 8.1 * 42.0  # IEC 61400-1 longitudinal integral scale above 60 m
KAIMAL_VERTICAL_LENGTH_M = 0.66 * 42.0  # IEC 61400-1 vertical integral scale above 60 m
BAND_HZ = (0.005, 0.2)
MIN_WIND_MPS = 0.5


@dataclass(frozen=True)
class WindProcess:
    tau_s: float  # time constant of the wind rate
    q_rate: float  # intensity of the rate's driving noise, (m/s^2)^2 / (1/s) = m^2/s^5
    q_walk: float  # equivalent random-walk intensity of the wind in the band, m^2/s^3

    @property
    def sigma_rate_mps2(self) -> float:
        """Stationary standard deviation of the wind rate."""
        return math.sqrt(0.5 * self.q_rate * self.tau_s)


def kaimal_felt_psd(f_hz: float, mean_mps: float, turbulence_intensity: float, diameter_m: float) -> float:
    """One-sided along-wind Kaimal spectrum as felt by a sphere of the given diameter, (m/s)^2/Hz."""
    u = max(mean_mps, MIN_WIND_MPS)
    sigma = turbulence_intensity * u
    t = KAIMAL_LENGTH_M / u
    x = math.pi * f_hz * diameter_m / u
    sinc = math.sin(x) / x if x > 1e-9 else 1.0
    return 4.0 * sigma * sigma * t / (1.0 + 6.0 * f_hz * t) ** (5.0 / 3.0) * sinc * sinc


def kaimal_window_share(window_s: float, mean_mps: float) -> float:
    """The share of the along-wind Kaimal variance that a window of ``window_s`` sees about its own mean,
    1 - int S(f) sinc^2(f T) df / sigma_u^2 (the slow part passes as the window's mean): 0.26 in 60 s at
    2 m/s, 0.51 at 8 m/s. A fit, 1 - (1 + 0.465 x^0.714)^-1.538 with x = T U / L, within 0.005 of the integral
    for x in 0.09-40 (0.5-230 m/s in 60 s) and never above it (the variance inferred from a window is never
    too small)."""
    x = window_s * max(mean_mps, MIN_WIND_MPS) / KAIMAL_LENGTH_M
    return 1.0 - (1.0 + 0.465 * x**0.714) ** -1.538


def vertical_air_samples(dt_s: float, mean_mps: float) -> float:
    """How many samples of ``dt_s`` one independent sample of the vertical air is worth: its Kaimal spectrum's
    one-sided S(0) = 4 sigma_w^2 L_w / U equals white samples' 2 R dt when R = sigma_w^2 (2 L_w / U) / dt, twice the
    integral time scale L_w / U over the interval (at least one): 13 s at 4.25 m/s, 261 samples at 20 Hz."""
    return max(1.0, 2.0 * KAIMAL_VERTICAL_LENGTH_M / (max(mean_mps, MIN_WIND_MPS) * dt_s))


def wind_process(mean_mps: float, turbulence_intensity: float, diameter_m: float, points: int = 40) -> WindProcess:
    """The integrated-OU wind model matched to the Kaimal spectrum in ``BAND_HZ`` (module docstring)."""
    u = max(mean_mps, MIN_WIND_MPS)
    lo, hi = BAND_HZ
    acc = 0.0
    for i in range(points):
        f = lo * (hi / lo) ** (i / (points - 1))
        w = 2.0 * math.pi * f
        acc += math.log(kaimal_felt_psd(f, u, turbulence_intensity, diameter_m) * w * w / 2.0)
    q_walk = math.exp(acc / points)  # geometric mean: least squares on log S
    tau = diameter_m / u
    return WindProcess(tau_s=tau, q_rate=q_walk / (tau * tau), q_walk=q_walk)
