"""Wind generation: Van der Hoven low-frequency band (paper Eqs. 1-2), IEC 61400-1 Kaimal turbulence
above the spectral gap, a multisine for frequency-response tests (along the mean wind, or along and
across it), and a steady wind.

All generators are vectorised: a flight of up to ``STREAM_ABOVE_S`` is synthesised up front (inverse FFT for the
unit-consistent spectra, a matrix of cosines for the paper's 47 discrete lines), so the cost per
simulated sample does not depend on the number of frequency lines. Longer flights are made block by
block (``WindStream``), so the simulator's memory does not grow with the duration. The wind field is uniform in
space (no shear); the balloon sees it at its own position.
"""

from __future__ import annotations

import csv
import functools
import math
from dataclasses import dataclass
from importlib import resources

import numpy as np

from balloon_core.config import ConfigError, build_section

SECONDS_PER_HOUR = 3600.0
KAIMAL_LAMBDA_M = 42.0  # IEC 61400-1 turbulence scale parameter above 60 m height
IEC_IREF = {"A": 0.16, "B": 0.14, "C": 0.12}


@dataclass(frozen=True)
class WindConfig:
    kind: str = "vdh"  # vdh | multisine | steady
    mean_mps: float = 3.0
    from_deg: float = 270.0  # meteorological: where the wind comes from (270 = westerly, blows east)
    vdh_amplitude: str = "consistent"  # consistent: A = sqrt(2 S df); paper: Eq. (2) as printed
    gap_cph: float = 5.0  # Van der Hoven below this frequency, Kaimal above (no band counted twice)
    turbulence: str = "kaimal"  # kaimal | none
    turbulence_intensity: float = 0.10  # sigma_u / U (Cabauw 8.5 % at 99 m); ignored if iec_class set
    iec_class: str = ""  # "A" | "B" | "C": sigma_u = I_ref (0.75 U + 5.6)
    vertical: bool = True  # also a Kaimal w component (the real world; the paper's scenarios turn it off)
    multisine_hz: tuple[float, ...] = (0.003, 0.01, 0.02, 0.05, 0.1, 0.2)
    multisine_amplitude_mps: float = 0.3
    multisine_axes: str = "along"  # along: u only; both: also the cross-wind v, same lines, own phases
    sample_hz: float = 20.0
    # the wind turns: a front, a sea breeze setting in, the day's veer. From turn_start_s the direction it comes from
    # moves by turn_deg (positive clockwise: veering) over turn_duration_s, smoothly (a half cosine: at most
    # pi / 2 turn_deg / turn_duration_s), the fluctuations turning with it (``wind_direction_deg``)
    turn_deg: float = 0.0
    turn_start_s: float = 0.0
    turn_duration_s: float = 600.0

    def __post_init__(self) -> None:
        if self.kind not in ("vdh", "multisine", "steady"):
            raise ConfigError(f"wind.kind must be vdh, multisine or steady, got {self.kind!r}")
        if self.vdh_amplitude not in ("consistent", "paper"):
            raise ConfigError(f"wind.vdh_amplitude must be consistent or paper, got {self.vdh_amplitude!r}")
        if self.turbulence not in ("kaimal", "none"):
            raise ConfigError(f"wind.turbulence must be kaimal or none, got {self.turbulence!r}")
        if self.multisine_axes not in ("along", "both"):
            raise ConfigError(f"wind.multisine_axes must be along or both, got {self.multisine_axes!r}")
        if self.iec_class not in ("", "A", "B", "C"):
            raise ConfigError(f"wind.iec_class must be A, B or C, got {self.iec_class!r}")
        if self.mean_mps < 0 or self.sample_hz <= 0 or self.gap_cph <= 0:
            raise ConfigError("wind.mean_mps >= 0, sample_hz > 0 and gap_cph > 0 are required")
        if self.sample_hz / 2 <= max(self.multisine_hz, default=0.0):
            raise ConfigError("wind.multisine_hz must lie below the Nyquist frequency of sample_hz")
        if not (math.isfinite(self.turn_deg) and self.turn_start_s >= 0.0 and self.turn_duration_s >= 1.0):
            raise ConfigError("wind.turn_deg must be finite, turn_start_s >= 0 and turn_duration_s >= 1 s")

    @property
    def sigma_u_mps(self) -> float:
        if self.iec_class:
            return IEC_IREF[self.iec_class] * (0.75 * self.mean_mps + 5.6)
        return self.turbulence_intensity * self.mean_mps

    @classmethod
    def from_dict(cls, values: dict) -> WindConfig:
        if "multisine_hz" in values:
            values = dict(values, multisine_hz=tuple(float(f) for f in values["multisine_hz"]))
        return build_section(cls, "wind", values)


# ---------------------------------------------------------------- spectra (pure functions)


@functools.lru_cache(maxsize=1)
def load_van_der_hoven() -> tuple[np.ndarray, np.ndarray]:
    """The shipped 48-point digitisation: (f in Hz, f*S(f) in (m/s)^2)."""
    text = resources.files("sim_hil").joinpath("data/van_der_hoven_spectrum.csv").read_text()
    rows = [r for r in csv.reader(line for line in text.splitlines() if line and not line.startswith("#"))]
    data = np.array([[float(a), float(b)] for a, b in rows[1:]])
    return data[:, 0] / SECONDS_PER_HOUR, data[:, 1]


def van_der_hoven_psd(f_hz: np.ndarray) -> np.ndarray:
    """One-sided PSD S(f) in (m/s)^2/Hz: f*S interpolated linearly in ln f, zero outside the table."""
    f_tab, fs_tab = load_van_der_hoven()
    f = np.asarray(f_hz, dtype=float)
    out = np.zeros_like(f)
    inside = (f >= f_tab[0]) & (f <= f_tab[-1])
    out[inside] = np.interp(np.log(f[inside]), np.log(f_tab), fs_tab) / f[inside]
    return out


def kaimal_psd(f_hz: np.ndarray, sigma_mps: float, length_scale_m: float, mean_mps: float) -> np.ndarray:
    """IEC 61400-1 Kaimal one-sided PSD S(f) = 4 sigma^2 (L/U) / (1 + 6 f L/U)^(5/3)."""
    lu = length_scale_m / max(mean_mps, 0.1)
    return 4.0 * sigma_mps**2 * lu / (1.0 + 6.0 * np.asarray(f_hz) * lu) ** (5.0 / 3.0)


KAIMAL_COMPONENTS = {  # (sigma ratio to sigma_u, integral length scale L_k = ratio * Lambda)
    "u": (1.0, 8.1),
    "v": (0.8, 2.7),
    "w": (0.5, 0.66),
}


def longitudinal_psd(cfg: WindConfig, f_hz: np.ndarray) -> np.ndarray:
    """Unit-consistent target PSD of the along-wind component: VdH below the gap, Kaimal above."""
    f = np.asarray(f_hz, dtype=float)
    gap_hz = cfg.gap_cph / SECONDS_PER_HOUR
    s = np.where(f < gap_hz, van_der_hoven_psd(f), 0.0)
    if cfg.turbulence == "kaimal":
        s = s + above_gap_psd(cfg, "u", f)
    return s


def component_kaimal_psd(cfg: WindConfig, comp: str, f_hz: np.ndarray) -> np.ndarray:
    ratio, scale = KAIMAL_COMPONENTS[comp]
    return kaimal_psd(f_hz, ratio * cfg.sigma_u_mps, scale * KAIMAL_LAMBDA_M, cfg.mean_mps)


def above_gap_psd(cfg: WindConfig, comp: str, f_hz: np.ndarray) -> np.ndarray:
    """Kaimal PSD of one component, zero below the spectral gap (that band belongs to Van der Hoven)."""
    f = np.asarray(f_hz, dtype=float)
    return np.where(f >= cfg.gap_cph / SECONDS_PER_HOUR, component_kaimal_psd(cfg, comp, f), 0.0)


def paper_line_amplitudes(f_lo_hz: float, f_hi_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Paper Eq. (2) as printed, on the table's own lines inside [f_lo, f_hi):
    A_i = (2/pi) sqrt(((S_i + S_{i+1})/2) (w_{i+1} - w_i)) with w in rad/s and S in (m/s)^2/Hz.

    Its variance sum(A_i^2)/2 = (4/pi) sum(S_mean df) is 4/pi = 1.27 times the trapezoidal integral of S.
    Returns (angular frequencies w_i in rad/s, amplitudes in m/s).
    """
    f_tab, fs_tab = load_van_der_hoven()
    s_tab = fs_tab / f_tab
    w = 2.0 * math.pi * f_tab
    amp = (2.0 / math.pi) * np.sqrt(0.5 * (s_tab[:-1] + s_tab[1:]) * np.diff(w))
    keep = (f_tab[:-1] >= f_lo_hz) & (f_tab[:-1] < f_hi_hz)
    return w[:-1][keep], amp[keep]


# ---------------------------------------------------------------- synthesis


def fft_grid(duration_s: float, sample_hz: float) -> tuple[int, float]:
    """Length M (even) of the synthesis grid covering the flight and its frequency step 1/(M dt)."""
    n = int(math.ceil(duration_s * sample_hz)) + 2
    m = n + (n % 2)
    return m, sample_hz / m


def band_variances(psd_fn, m: int, df: float) -> np.ndarray:
    """Variance of S in each FFT bin [f_k - df/2, f_k + df/2], k = 0..M/2, by quadrature of the
    cumulative integral on a fine logarithmic grid (exact for the low, coarse bins where a Riemann sum
    S(f_k) df would over-count a steep spectrum)."""
    edges = (np.arange(m // 2 + 2) - 0.5) * df
    edges[0] = 0.0
    fine = np.geomspace(df / 8.0, edges[-1], 400_000)
    s = psd_fn(fine)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (s[1:] + s[:-1]) * np.diff(fine))])
    return np.diff(np.interp(edges, fine, cum, left=0.0))


def synthesize(var: np.ndarray, m: int, rng: np.random.Generator) -> np.ndarray:
    """Sum of cosines A_k cos(2 pi f_k t + phi_k), A_k = sqrt(2 var_k), f_k = k df (k = 1..M/2-1),
    uniform random phases, evaluated at all M samples with one inverse real FFT (paper Eq. 1 on a
    uniform grid). ``var`` holds the band variance of each bin k = 0..M/2 (DC and Nyquist unused), so
    the series' variance is the integral of S over [df/2, (M/2 - 1/2) df]."""
    amp = np.sqrt(2.0 * var)
    amp[0] = 0.0
    amp[-1] = 0.0
    phases = rng.uniform(0.0, 2.0 * math.pi, size=amp.size)
    spectrum = 0.5 * m * amp * np.exp(1j * phases)
    return np.fft.irfft(spectrum, n=m)


@dataclass(frozen=True)
class WindSeries:
    """A generated wind: NED air velocity and its time derivative, sampled every ``dt_s`` from t = 0."""

    dt_s: float
    ned: np.ndarray  # (n, 3) m/s
    rate: np.ndarray  # (n, 3) m/s^2

    def window(self, i0: int, i1: int) -> tuple[np.ndarray, np.ndarray]:
        """NED wind and its rate at samples i0 .. i1 (clipped to the series)."""
        i0, i1 = max(0, i0), min(len(self.ned) - 1, i1)
        return self.ned[i0 : i1 + 1], self.rate[i0 : i1 + 1]


def spatial_average(x: np.ndarray, sample_hz: float, length_m: float, mean_mps: float) -> np.ndarray:
    """The wind a body of size ``length_m`` feels: frozen turbulence (Taylor) averaged along the wind
    over the body, i.e. a moving average over L/U seconds, applied as its transfer function
    sinc(f L / U) on the periodic grid. Eddies smaller than the balloon push on it from both sides."""
    if length_m <= 0.0 or mean_mps <= 0.0:
        return x
    f = np.fft.rfftfreq(len(x), 1.0 / sample_hz)
    return np.fft.irfft(np.fft.rfft(x) * np.sinc(f * length_m / mean_mps), n=len(x))


def multisine(freqs_hz: tuple[float, ...], amplitude_mps: float, phases: np.ndarray, t: np.ndarray) -> np.ndarray:
    """sum_k A cos(2 pi f_k t + phi_k): equal-amplitude lines at the given frequencies."""
    x = np.zeros(t.shape)
    for fk, ph in zip(freqs_hz, phases, strict=True):
        x += amplitude_mps * np.cos(2.0 * math.pi * fk * t + ph)
    return x


def wind_components(
    cfg: WindConfig, duration_s: float, seed: int, averaging_length_m: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fluctuations of one flight in wind axes: along-wind u, cross-wind v (90 deg to the right
    of the direction the wind blows to), down w, before the mean is added and the axes rotated."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x57494E44]))
    m, df = fft_grid(duration_s, cfg.sample_hz)
    t = np.arange(m) / cfg.sample_hz
    u = np.zeros(m)
    v = np.zeros(m)
    w = np.zeros(m)
    if cfg.kind == "vdh":
        if cfg.vdh_amplitude == "consistent":
            u += synthesize(band_variances(lambda x: longitudinal_psd(cfg, x), m, df), m, rng)
        else:
            omega, amp = paper_line_amplitudes(0.0, cfg.gap_cph / SECONDS_PER_HOUR)
            xi = rng.uniform(0.0, 2.0 * math.pi, size=amp.size)
            for k in range(amp.size):  # 47 lines at most: vectorised over time
                u += amp[k] * np.cos(omega[k] * t + xi[k])
            if cfg.turbulence == "kaimal":
                u += synthesize(band_variances(lambda x: above_gap_psd(cfg, "u", x), m, df), m, rng)
        if cfg.turbulence == "kaimal":
            v += synthesize(band_variances(lambda x: above_gap_psd(cfg, "v", x), m, df), m, rng)
            if cfg.vertical:
                w += synthesize(band_variances(lambda x: above_gap_psd(cfg, "w", x), m, df), m, rng)
    elif cfg.kind == "multisine":
        n_lines = len(cfg.multisine_hz)
        u += multisine(cfg.multisine_hz, cfg.multisine_amplitude_mps, rng.uniform(0.0, 2.0 * math.pi, n_lines), t)
        if cfg.multisine_axes == "both":  # drawn after u's phases: the along-wind series is unchanged
            v += multisine(cfg.multisine_hz, cfg.multisine_amplitude_mps, rng.uniform(0.0, 2.0 * math.pi, n_lines), t)
    if averaging_length_m > 0.0 and cfg.kind == "vdh":
        u, v, w = (spatial_average(c, cfg.sample_hz, averaging_length_m, cfg.mean_mps) for c in (u, v, w))
    return u, v, w


def generate_wind(cfg: WindConfig, duration_s: float, seed: int, averaging_length_m: float = 0.0) -> WindSeries:
    """The wind for one flight: along-wind u, cross-wind v, vertical w (``wind_components``), rotated
    into NED, optionally as felt by a body of the given size (``spatial_average``)."""
    u, v, w = wind_components(cfg, duration_s, seed, averaging_length_m)
    ned = to_ned(cfg, u, v, w, np.arange(u.size) / cfg.sample_hz)
    rate = np.gradient(ned, 1.0 / cfg.sample_hz, axis=0)
    return WindSeries(1.0 / cfg.sample_hz, ned, rate)


# ---------------------------------------------------------------- long flights: the wind in blocks

STREAM_ABOVE_S = 2 * SECONDS_PER_HOUR  # longer flights are synthesised block by block (WindStream)
SPLIT_HZ = 0.01  # below: one series for the whole flight on a coarse grid; above: overlapping blocks
COARSE_HZ = 1.0  # sample rate of the low band (linear interpolation error < 2e-4 of a 0.01 Hz line)
BLOCK_SAMPLES = 2**16  # high-band block: 55 min at 20 Hz, lines every 0.0003 Hz (1/33 of SPLIT_HZ)


class WindStream:
    """The wind of a long flight without holding the flight: memory does not grow with the duration
    (a few MB whatever it is), the series is continuous and deterministic for a seed.

    The spectrum is split at ``SPLIT_HZ``. Below it, a random-phase sum of cosines on the flight's own
    frequency grid (as ``generate_wind``), synthesised once at ``COARSE_HZ`` (a day is 86 400 samples)
    and interpolated. Above it, independent random-phase blocks of ``BLOCK_SAMPLES`` overlap by half and
    are cross-faded with sine windows (w_j^2 + w_j+1^2 = 1), so the variance stays that of the band at
    every instant and the spectrum is the band's, smoothed over 2 / block length. Block j draws its
    phases from its own seed, so any stretch of the flight is made without the ones before it.
    The paper's discrete lines and the multisine are evaluated directly at the requested times."""

    def __init__(self, cfg: WindConfig, duration_s: float, seed: int, averaging_length_m: float = 0.0,
                 block_samples: int = BLOCK_SAMPLES) -> None:  # fmt: skip
        self.cfg = cfg
        self.dt_s = 1.0 / cfg.sample_hz
        self.n = int(math.ceil(duration_s * cfg.sample_hz)) + 2
        self.seed = seed
        self.block = block_samples - block_samples % 2
        self.length_m = averaging_length_m if cfg.kind == "vdh" else 0.0
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0x57494E44]))
        self.psds = self._component_psds()
        self.coarse_hz = COARSE_HZ
        mc, dfc = fft_grid(duration_s, COARSE_HZ)
        self.low = np.zeros((3, mc))
        self.high_var: dict[int, np.ndarray] = {}
        for k, psd in self.psds.items():
            low = band_variances(lambda f, p=psd: np.where(f < SPLIT_HZ, p(f), 0.0), mc, dfc)
            self.low[k] = synthesize(low * self._felt(np.arange(low.size) * dfc), mc, rng)
            dfb = cfg.sample_hz / self.block
            high = band_variances(lambda f, p=psd: np.where(f >= SPLIT_HZ, p(f), 0.0), self.block, dfb)
            self.high_var[k] = high * self._felt(np.arange(high.size) * dfb)
        self.lines = None
        if cfg.kind == "vdh" and cfg.vdh_amplitude == "paper":
            omega, amp = paper_line_amplitudes(0.0, cfg.gap_cph / SECONDS_PER_HOUR)
            self.lines = (omega, amp, rng.uniform(0.0, 2.0 * math.pi, size=amp.size))
        self.ms_phases = None
        if cfg.kind == "multisine":
            n_lines = len(cfg.multisine_hz)
            u = rng.uniform(0.0, 2.0 * math.pi, n_lines)
            v = rng.uniform(0.0, 2.0 * math.pi, n_lines) if cfg.multisine_axes == "both" else None
            self.ms_phases = (u, v)
        self._cache: dict[int, np.ndarray] = {}

    def _component_psds(self) -> dict:
        cfg = self.cfg
        out = {}
        if cfg.kind != "vdh":
            return out
        if cfg.vdh_amplitude == "consistent":
            out[0] = lambda f: longitudinal_psd(cfg, f)
        elif cfg.turbulence == "kaimal":
            out[0] = lambda f: above_gap_psd(cfg, "u", f)
        if cfg.turbulence == "kaimal":
            out[1] = lambda f: above_gap_psd(cfg, "v", f)
            if cfg.vertical:
                out[2] = lambda f: above_gap_psd(cfg, "w", f)
        return out

    def _felt(self, f: np.ndarray) -> np.ndarray:
        """Variance factor of the averaging over the body (``spatial_average``): sinc^2(f L / U)."""
        if self.length_m <= 0.0 or self.cfg.mean_mps <= 0.0:
            return np.ones_like(f)
        return np.sinc(f * self.length_m / self.cfg.mean_mps) ** 2

    def _block(self, j: int) -> np.ndarray:
        if j not in self._cache:
            if len(self._cache) >= 4:
                self._cache.pop(min(self._cache))  # the flight runs forward: drop the oldest
            rng = np.random.default_rng(np.random.SeedSequence([self.seed, 0x57494E44, 1, j + 1]))
            y = np.zeros((3, self.block))
            for k, var in self.high_var.items():
                y[k] = synthesize(var, self.block, rng)
            self._cache[j] = y
        return self._cache[j]

    def components(self, i0: int, i1: int) -> np.ndarray:
        """(3, i1 - i0 + 1): u, v, w at samples i0 .. i1."""
        idx = np.arange(i0, i1 + 1)
        t = idx * self.dt_s
        out = np.zeros((3, idx.size))
        if self.high_var:
            half = self.block // 2
            for j in range(i0 // half - 1, i1 // half + 1):
                start = j * half
                sel = (idx >= start) & (idx < start + self.block)
                if not sel.any():
                    continue
                n = idx[sel] - start
                out[:, sel] += np.sin(math.pi * (n + 0.5) / self.block) * self._block(j)[:, n]
            grid = np.arange(self.low.shape[1]) / self.coarse_hz
            for k in self.high_var:
                out[k] += np.interp(t, grid, self.low[k])
        if self.lines is not None:
            omega, amp, xi = self.lines
            for k in range(amp.size):
                out[0] += amp[k] * np.cos(omega[k] * t + xi[k])
        if self.ms_phases is not None:
            u, v = self.ms_phases
            out[0] += multisine(self.cfg.multisine_hz, self.cfg.multisine_amplitude_mps, u, t)
            if v is not None:
                out[1] += multisine(self.cfg.multisine_hz, self.cfg.multisine_amplitude_mps, v, t)
        return out

    def window(self, i0: int, i1: int) -> tuple[np.ndarray, np.ndarray]:
        """NED wind and its rate, (i1 - i0 + 1, 3) each, at samples i0 .. i1 (as ``WindSeries.window``)."""
        i0, i1 = max(0, i0), min(self.n - 1, i1)
        lo, hi = max(0, i0 - 1), min(self.n - 1, i1 + 1)
        ned = to_ned(self.cfg, *self.components(lo, hi), np.arange(lo, hi + 1) * self.dt_s)
        rate = np.gradient(ned, self.dt_s, axis=0)
        return ned[i0 - lo : i1 - lo + 1], rate[i0 - lo : i1 - lo + 1]


def wind_direction_deg(cfg: WindConfig, t_s: np.ndarray) -> np.ndarray:
    """Where the mean wind comes from at times ``t_s``, deg (meteorological): ``from_deg``, and from ``turn_start_s``
    on ``turn_deg`` more over ``turn_duration_s`` along a half cosine (no step in the direction nor in its rate)."""
    x = np.clip((np.asarray(t_s, float) - cfg.turn_start_s) / cfg.turn_duration_s, 0.0, 1.0)
    return cfg.from_deg + cfg.turn_deg * 0.5 * (1.0 - np.cos(math.pi * x))


def to_ned(cfg: WindConfig, u: np.ndarray, v: np.ndarray, w: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """Along-wind, cross-wind and down fluctuations plus the mean wind, in NED, (n, 3), at times ``t_s`` (the wind
    axes turn with the mean direction: ``wind_direction_deg``)."""
    if cfg.turn_deg:
        to_rad = np.radians(wind_direction_deg(cfg, t_s) + 180.0)
        c, s = np.cos(to_rad), np.sin(to_rad)
    else:  # one direction (math's cos and sin: the same bits as before the wind could turn)
        c, s = math.cos(math.radians(cfg.from_deg + 180.0)), math.sin(math.radians(cfg.from_deg + 180.0))
    speed = cfg.mean_mps + u
    return np.column_stack([speed * c - v * s, speed * s + v * c, w])


def wind_source(cfg: WindConfig, duration_s: float, seed: int, averaging_length_m: float = 0.0):
    """The wind of one flight for the simulator: the whole-flight series (``generate_wind``) up to
    ``STREAM_ABOVE_S``, a ``WindStream`` (memory independent of the duration) beyond."""
    if duration_s > STREAM_ABOVE_S:
        return WindStream(cfg, duration_s, seed, averaging_length_m)
    return generate_wind(cfg, duration_s, seed, averaging_length_m)
