"""The lockstep harness: the C core and the Python reference on the same sample stream, compared after
every sample (docs/porting.md, "What the harness proves").

Compared at every step: what ``on_imu`` returned, the mode, the reset counters (in all and per kind),
every input counter, the consistency flags (exactly, but for a float32 windowed NIS within its rounding of a flag's
threshold, `_threshold_flip`); the state x, the standard deviations sqrt(diag P)
and the WIND_COV fields (within ``TOLERANCES``). The double build is held against the Python core in
float64, the float build (the firmware as flown) against the Python core's float32 mode.

The tolerances are the rounding each build carries, not a fit: in double the two cores differ only in
the order of the sums (the C products skip zeros and keep P symmetric), 1e-13 relative after hours;
in float32 both round at 6e-8 relative per operation, but in different places (the Python core's
scalars are float64 between its float32 arrays), and the filter's own contraction bounds what that
rounding grows to: millimetres of position and 1e-3 m/s of wind over a flight (measured on every
scenario: ``python -m firmware_py.lockstep``). A model or logic difference is many times larger (a
wrong sign, a missed row, a different gate) and shows in the mode or reset sequence first.

Also writes and reads the binary sample streams that ``firmware_c/replay`` (host, sanitisers, QEMU)
replays, and their outputs.

    python -m firmware_py.lockstep FLIGHT.tlog|CAPTURE.raw [--config FILE.toml] [--float32]
"""

from __future__ import annotations

import dataclasses
import math
import struct
import sys
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from balloon_core.config import Design
from balloon_core.samples import BaroSample, GroundBaroSample, ImuSample, Sample, WinchSample
from firmware_py.core_c import COUNTER_NAMES, CEstimator, CWindCovOutput, config_struct, load
from firmware_py.estimator.consistency import FLAG_NIS, FLAG_NIS_CLEAR
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.outputs import WindCovOutput
from firmware_py.estimator.state import N_STATES, STATE_NAMES, FilterConfig
from firmware_py.streams import feed_ground

# absolute tolerances per state (and per sqrt(P) of that state): double, float32
_UNIT_TOL = {  # by the state's unit: what float32 rounding grows to over a flight, measured x 10
    "pos": 0.05, "vel": 5e-3, "att": 1e-4, "gbias": 1e-5, "wind": 5e-3, "wrate": 1e-3, "drag": 1e-3,
    "baro": 0.05, "abias": 1e-4,
}  # fmt: skip
DOUBLE_RTOL = 1e-9  # of max(1, |value|)
# ... and in float32 a standard deviation also carries a share of itself: a variance that one step's fusions bring
# down K times loses K times float32's relative rounding (a gap's lost attitude, 0.44 rad, re-anchored to 0.013 rad
# in a step: K = 1100, the two builds' sigma 1.8 % apart for two samples)
FLOAT_SIGMA_RTOL = 0.03


def _unit(name: str) -> str:
    return next(u for u in _UNIT_TOL if name.startswith(u))


FLOAT_TOL = np.array([_UNIT_TOL[_unit(n)] for n in STATE_NAMES])
WINDCOV_FIELDS = ("wind_x", "wind_y", "var_horiz", "wind_alt", "horiz_accuracy")
FLOAT_WINDCOV_TOL = np.array([5e-3, 5e-3, 5e-3, 0.05, 5e-3])


def windcov_tolerance(real: str, values: np.ndarray) -> np.ndarray:
    """WIND_COV is float32 on the wire: half an ulp of float32 on top of the core's own difference."""
    ulp = np.abs(values) * 2.0**-23
    if real == "double":
        return DOUBLE_RTOL * np.maximum(1.0, np.abs(values)) + ulp
    return FLOAT_WINDCOV_TOL + ulp


@dataclass
class Report:
    """The largest differences and the first discrete mismatch of one lockstep run."""

    real: str
    samples: int = 0
    steps: int = 0
    max_dx: np.ndarray = field(default_factory=lambda: np.zeros(N_STATES))
    max_dsigma: np.ndarray = field(default_factory=lambda: np.zeros(N_STATES))
    max_windcov: np.ndarray = field(default_factory=lambda: np.zeros(len(WINDCOV_FIELDS)))
    worst_ratio: float = 0.0  # the largest difference over its tolerance (<= 1: equal)
    mismatch: str = ""  # the first discrete difference (mode, resets, counters, flags, return value)
    reset_counts: tuple[int, ...] = ()  # the Python core's at the end, per kind (what the run went through)
    counters: dict[str, int] = dataclasses.field(default_factory=dict)  # the Python core's at the end

    @property
    def equal(self) -> bool:
        return not self.mismatch and self.worst_ratio <= 1.0

    def lines(self) -> list[str]:
        verdict = "EQUAL" if self.equal else "DIFFERENT"
        out = [f"{self.samples} samples, {self.steps} filter steps, {self.real} build: {verdict} "
               f"(worst difference {self.worst_ratio:.2g} of its tolerance)"]  # fmt: skip
        if self.mismatch:
            out.append(f"  first mismatch: {self.mismatch}")
        top = np.argsort(-self.max_dx)[:4]
        out.append("  largest |dx|: " + ", ".join(f"{STATE_NAMES[i]} {self.max_dx[i]:.2g}" for i in top))
        top = np.argsort(-self.max_dsigma)[:3]
        out.append("  largest |d sigma|: " + ", ".join(f"{STATE_NAMES[i]} {self.max_dsigma[i]:.2g}" for i in top))
        out.append("  largest WIND_COV difference: "
                   + ", ".join(f"{n} {v:.2g}" for n, v in zip(WINDCOV_FIELDS, self.max_windcov)))  # fmt: skip
        return out


FLAGS_AT = 4  # the consistency flags' place in _discrete's tuple
FLAG_RTOL = 1e-4  # a windowed NIS this close to a flag's threshold (relative) may cross it a sample apart in float32


def _discrete(est) -> tuple:
    e = est.ekf
    counters = est.counters.as_dict()
    return (e.mode, e.reset_count, tuple(e.reset_counts), tuple(counters[n] for n in COUNTER_NAMES),
            est.consistency.flags, bool(est.unconfirmed), est.winch_samples, est.ground_samples,
            est.winch_rejected, est.ground_rejected, est.winch_reject_reason, est.ground_reject_reason)  # fmt: skip


def _threshold_flip(py, da: tuple, db: tuple) -> bool:
    """The float build's consistency flags differ from the Python core's in sources whose windowed NIS lies within
    float32's rounding (``FLAG_RTOL``) of a flag's threshold, and nothing else differs: one core crossed it a sample
    before the other (1.50002 against 1.49999). The states that follow stay within their tolerances, checked apart."""
    if da[:FLAGS_AT] + da[FLAGS_AT + 1 :] != db[:FLAGS_AT] + db[FLAGS_AT + 1 :]:
        return False
    bits = da[FLAGS_AT] ^ db[FLAGS_AT]
    nis = py.consistency.nis
    return all(min(abs(nis[i] - t) for t in (FLAG_NIS, FLAG_NIS_CLEAR)) <= FLAG_RTOL * FLAG_NIS
               for i in range(len(nis)) if bits >> i & 1)  # fmt: skip


def run(design: Design, cfg: FilterConfig, samples: Iterable[Sample], coast_every: int = 0) -> Report:
    """Both cores on ``samples`` (``ImuSample`` / ``BaroSample``, as the firmware feeds them), compared after
    each. ``cfg.float32`` picks the float pair, else the double pair. ``coast_every`` > 0 also calls
    ``coast(0.1)`` on both every that many samples (the live firmware's silence)."""
    cfg = dataclasses.replace(cfg, core="py")
    py = Estimator(design, cfg)
    c = CEstimator(design, cfg)
    po, co = WindCovOutput(cfg.imu_rate_hz, design.site.altitude_amsl_m), CWindCovOutput(c)
    rep = Report(real=c.real)
    tol_x = FLOAT_TOL if c.real == "float" else None
    for k, s in enumerate(samples):
        rep.samples += 1
        if type(s) is BaroSample:
            a = py.on_baro(s.t_us, s.pressure_hpa, s.temperature_c)
            b = c.on_baro(s.t_us, s.pressure_hpa, s.temperature_c)
        elif type(s) is WinchSample or type(s) is GroundBaroSample:
            a, b = feed_ground(py, s), feed_ground(c, s)
        else:
            a = py.on_imu(*s)
            b = c.on_imu(*s)
            if a:
                rep.steps += 1
                po.update(py, s.t_us)
                co.update(c, s.t_us)
        if coast_every and k % coast_every == coast_every - 1:
            py.coast(0.1)
            c.coast(0.1)
        if not rep.mismatch:
            da, db = _discrete(py), _discrete(c)
            if a != b or (da != db and not (c.real == "float" and _threshold_flip(py, da, db))):
                rep.mismatch = f"sample {k} (t = {s.t_us} us): Python {a, *da} / C {b, *db}"
        xp, xc = np.asarray(py.ekf.x, np.float64), np.asarray(c.ekf.x, np.float64)
        sp = np.sqrt(np.maximum(np.diag(np.asarray(py.ekf.P, np.float64)), 0.0))
        sc = np.sqrt(np.maximum(np.diag(np.asarray(c.ekf.P, np.float64)), 0.0))
        dx, ds = np.abs(xp - xc), np.abs(sp - sc)
        np.maximum(rep.max_dx, dx, out=rep.max_dx)
        np.maximum(rep.max_dsigma, ds, out=rep.max_dsigma)
        tx = DOUBLE_RTOL * np.maximum(1.0, np.abs(xp)) if tol_x is None else tol_x
        ts = DOUBLE_RTOL * np.maximum(1.0, sp) if tol_x is None else tol_x + FLOAT_SIGMA_RTOL * sp
        fp = np.array(po.fields(py)[1:], np.float64)[[0, 1, 3, 5, 6]]
        fc = np.array(co.fields(c)[1:], np.float64)[[0, 1, 3, 5, 6]]
        fp32 = fp.astype(np.float32).astype(np.float64)  # on the wire
        both_nan = np.isnan(fp32) & np.isnan(fc)
        dw = np.where(both_nan, 0.0, np.abs(fp32 - fc))
        dw = np.where(np.isnan(dw), np.inf, dw)  # NaN on one side only
        np.maximum(rep.max_windcov, dw, out=rep.max_windcov)
        tw = windcov_tolerance(c.real, np.nan_to_num(fp32))
        ratio = max(float(np.max(dx / tx)), float(np.max(ds / ts)), float(np.max(dw / tw)))
        if not math.isfinite(ratio):
            ratio = math.inf
        rep.worst_ratio = max(rep.worst_ratio, ratio)
    rep.reset_counts = tuple(int(n) for n in py.ekf.reset_counts)
    rep.counters = py.counters.as_dict()
    return rep


# ------------------------------------------------------------------ the replay program's files

RECORD = struct.Struct("<qii9d")
KIND_IMU, KIND_BARO, KIND_COAST, KIND_WINCH, KIND_GROUND = 0, 1, 2, 3, 4
OUT_DTYPE = np.dtype([("time_usec", "<i8"), ("advanced", "<i4"), ("mode", "<i4"), ("reset_count", "<i4"),
                      ("flags", "<i4"), ("f", "<f4", (5 + 2 * N_STATES,)), ("pad", "<i4")])  # fmt: skip


def write_stream(path: str, design: Design, cfg: FilterConfig, samples: Iterable[Sample]) -> int:
    """The design as bw_config_t (46 doubles) and the samples as 88-byte records, for firmware_c/replay.
    Returns the number of records."""
    _, Config, _, _ = load("float")
    n = 0
    with open(path, "wb") as f:
        f.write(bytes(config_struct(design, cfg, Config)))
        for s in samples:
            if type(s) is BaroSample:
                f.write(RECORD.pack(s.t_us, KIND_BARO, 0, s.pressure_hpa, s.temperature_c, *[0.0] * 7))
            elif type(s) is WinchSample:  # on the sensor clock of its arrival (streams.feed_ground)
                f.write(RECORD.pack(0, KIND_WINCH, 0, s.line_length_m, s.speed_mps, s.tension_n, *[0.0] * 6))
            elif type(s) is GroundBaroSample:
                f.write(RECORD.pack(0, KIND_GROUND, 0, s.pressure_hpa, s.temperature_c, *[0.0] * 7))
            else:
                f.write(RECORD.pack(s.t_us, KIND_IMU, 0, *s[1:]))
            n += 1
    return n


def read_outputs(path: str) -> np.ndarray:
    """What firmware_c/replay wrote: one record per IMU sample (``OUT_DTYPE``)."""
    return np.fromfile(path, OUT_DTYPE)


def compare_outputs(a: np.ndarray, b: np.ndarray, real: str = "float") -> tuple[bool, str]:
    """Two replay outputs (e.g. QEMU's and the host build's): the discrete fields identical, the
    values within the lockstep's tolerance for ``real``. (equal, one line)."""
    if len(a) != len(b):
        return False, f"{len(a)} against {len(b)} records"
    for name in ("time_usec", "advanced", "mode", "reset_count", "flags"):
        bad = np.nonzero(a[name] != b[name])[0]
        if len(bad):
            return False, f"{name} differs first at record {bad[0]}"
    fa, fb = a["f"].astype(np.float64), b["f"].astype(np.float64)
    var = slice(5 + N_STATES, 5 + 2 * N_STATES)  # the variances, compared as standard deviations
    fa[:, var], fb[:, var] = np.sqrt(np.maximum(fa[:, var], 0.0)), np.sqrt(np.maximum(fb[:, var], 0.0))
    same = (fa == fb) | (np.isnan(fa) & np.isnan(fb))
    d = np.where(same, 0.0, np.abs(fa - fb))
    d = np.where(np.isnan(d), np.inf, d)
    tol = np.concatenate([FLOAT_WINDCOV_TOL, FLOAT_TOL, FLOAT_TOL])
    if real == "double":
        tol = DOUBLE_RTOL * np.ones_like(tol)
    worst = float(np.max(d / (tol + np.abs(np.nan_to_num(fb)) * 2.0**-23), initial=0.0))
    identical = float(np.mean(same.all(axis=1))) * 100.0
    line = f"{len(a)} records, {identical:.1f} % bit-identical, worst difference {worst:.2g} of the tolerance"
    return worst <= 1.0, line


def capture_samples(path: str) -> Iterator[Sample]:
    """The sensor samples of a tlog or a raw capture, as the firmware reads them (a ULog or a DataFlash log:
    ``postflight.logs.read_flight(path).samples()``)."""
    from balloon_core.samples import MavlinkSampler
    from balloon_core.wire import LinkStats, capture_messages

    sampler = MavlinkSampler()
    for m in capture_messages(path, LinkStats()):
        yield from sampler.convert(m) or ()


def pipeline_samples(samples: Iterable[Sample], cfg: FilterConfig) -> tuple[list[Sample], FilterConfig]:
    """The samples after the firmware's input pipeline (rate measured, faster streams averaged), and the
    configuration at the rate it chose."""
    from firmware_py.streams import InputPipeline

    pipe = InputPipeline(cfg, False)
    out: list[Sample] = []
    for s in samples:
        out.extend(pipe.push(s))
    out.extend(pipe.flush())
    return out, pipe.cfg


def flight_samples(path: str, cfg: FilterConfig) -> tuple[list[Sample], FilterConfig]:
    """``pipeline_samples`` of a tlog or a raw capture."""
    return pipeline_samples(capture_samples(path), cfg)


def main(argv: Sequence[str] | None = None) -> int:
    from balloon_core import userargs
    from firmware_py.cli import load_config

    ap = userargs.Parser(prog="lockstep", description="the C core against the Python reference, step by step")
    ap.add_argument("flight", type=userargs.input_file, help=".tlog or raw capture")
    ap.add_argument("--config", type=userargs.input_file)
    ap.add_argument("--float32", action="store_true", help="the float build against the Python float32 mode")
    args = ap.parse_args(argv)
    from balloon_core.config import ConfigError
    from firmware_c.build import BuildError, library

    try:
        design, cfg, _ = load_config(args.config)
        cfg = dataclasses.replace(cfg, float32=args.float32)
        library("float" if args.float32 else "double")  # before any work: the harness runs the C core
        samples, cfg = flight_samples(args.flight, cfg)
        rep = run(design, cfg, samples)
    except BuildError as exc:
        return userargs.fail("lockstep", f"{exc} (the harness runs the C core beside the Python one)")
    except (ConfigError, ValueError, OSError) as exc:
        return userargs.fail("lockstep", exc)
    print("\n".join(rep.lines()))
    return 0 if rep.equal else 1


if __name__ == "__main__":
    sys.exit(main())

__all__ = ["ImuSample", "BaroSample", "Report", "run", "write_stream", "read_outputs", "compare_outputs"]
