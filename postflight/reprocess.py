"""Post-flight reprocessing: the firmware's estimator over a whole flight, then the backward pass of
the fixed-interval smoother (postflight/smoother.py), into a ``WindProduct``.

The samples come through the same interface the live firmware uses (balloon_core/samples.py), so the
forward pass is exactly what the balloon computed in flight, given the same design file."""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable, Iterable

import numpy as np

from balloon_core.config import Design, to_toml
from balloon_core.samples import BaroSample, GroundBaroSample, GroundSample, ImuSample, Sample, WinchSample
from balloon_core.score import direction_from_deg, wind_unknown
from firmware_py.app import CLOCK_STEP_MAX_US, ClockGuard
from firmware_py.estimator.control import Estimator
from firmware_py.estimator.state import (
    MODE_GROUND,
    MODE_TAUT,
    N_STATES,
    POS_D,
    POS_E,
    POS_N,
    WIND_E,
    WIND_N,
    FilterConfig,
)
from firmware_py.streams import InputPipeline, feed, feed_ground
from postflight.flight import CLOCK_BACK_US, CLOCK_JUMP_US, loss_notes, rejected_note, segment_note
from postflight.mavlink_log import SampleRows
from postflight.product import (
    FLAG_AFTER_GAP,
    FLAG_NO_BARO,
    FLAG_SEGMENT_START,
    FLAG_SMOOTHED,
    FLAG_WIND_UNKNOWN,
    WindProduct,
)
from postflight.smoother import BLOCK as BLOCK_C
from postflight.smoother import SmootherRecorder

GRID_HZ = 10.0  # the product's rate: WIND_COV's default
GAP_STEPS = 1.5  # IMU samples further apart than this many filter steps: samples are missing between them


def north_reference(declination_deg: float) -> str:
    """What the product's directions and its northward/eastward winds are measured from: true north where the
    design gave the site's magnetic declination, else magnetic north (a declination of 0 is taken as not given)."""
    if declination_deg == 0.0:
        return ("magnetic north: no magnetic declination given ([site] mag_declination_deg = 0), so directions and "
                "the northward/eastward winds are magnetic, not true")  # fmt: skip
    return f"true north: the site's magnetic declination {declination_deg:+g} deg (east positive) applied"


def design_toml(design: Design, cfg: FilterConfig) -> str:
    """The design a reprocessing used as a design file (the product's ``design_toml``): every section and
    key of the estimator's design with its value, defaults filled in, ``cfg`` as the run used it (the IMU
    rate the input pipeline chose, float64)."""
    sections: dict = {name: getattr(design, name) for name in ("balloon", "tether", "site", "sensors")}
    sections["filter"] = cfg
    text = to_toml(sections, "# the design used by balloon-gs reprocess, every value written out")
    if design.site.ground_pressure_hpa is None:
        text = text.replace("\n[sensors]", "# ground_pressure_hpa not given: the barometer zeroed at boot\n\n[sensors]")
    return text


def _signature(est: Estimator) -> tuple:
    """Where the smoother's chain is cut: the filter's own reset counter (every re-placement of the
    state goes through ``WindEkf.reset``), the mode (the model's equations change with it: held, free,
    taut) and whether the estimator is initialised at all (a reboot forgets everything)."""
    return est.initialised, est.ekf.mode, est.ekf.reset_count


def reprocess(
    samples: Iterable[Sample | GroundSample],
    design: Design,
    cfg: FilterConfig | None = None,
    rate_explicit: bool = True,
    grid_hz: float = GRID_HZ,
    progress: Callable[[int], None] | None = None,
    warn: Callable[[str], None] | None = None,
    store_dir: str | None = None,
    core: str | None = None,
) -> WindProduct:
    """Forward filter + backward smoother over ``samples`` (as logged, in order).

    The samples pass the live firmware's input pipeline (firmware_py/streams.py: the IMU rate measured
    from the stream unless ``rate_explicit``, a faster stream averaged down to the filter's step), so
    the forward pass is what the firmware computes. Where the sensor clock goes back by more than
    ``CLOCK_BACK_US`` (a reboot; less is reordering, the pipeline's) or jumps ahead by more than
    ``CLOCK_JUMP_US``, a new segment starts: its own pipeline, filter and smoother, joined into one
    product (``WindProduct.segment``). ``progress(n)`` is called every 10 000 samples with the count so
    far; ``warn`` gets the pipeline's one-line warnings; ``store_dir``: where the smoother's store spills
    (``SmootherRecorder``), else memory; ``core``: the estimator the forward pass runs, "c" (the C core's
    double build, in blocks: ``_CRun``) or "py" (the Python reference), None: C where it can be built."""
    # the smoother works in float64 and records every step of the filter: the C core's recorder (its double
    # build, host/reprocess.c) where a C compiler is, else the Python core's (``core``: "c", "py", None: C if
    # it can be built)
    use_c = c_core_available() if core is None else core == "c"
    # the product's design says which core ran (its double build: the smoother works in float64)
    cfg = dataclasses.replace(cfg or FilterConfig(), float32=False, core="c" if use_c else "py")
    parts: list[WindProduct] = []
    tally = _SourceTally()
    seg = _Segment(design, cfg, rate_explicit, grid_hz, store_dir, use_c)
    newest = None  # the newest sample time in this segment
    i = 0
    # a sample off the clock is held until IMU samples run on from it, as the firmware holds it (ClockGuard): a reboot
    # or a silence then, a glitch (one sample stamped 0, an hour ahead) dropped if the old clock comes first (it split
    # the flight in three)
    clock = ClockGuard()

    def guard(s) -> None:
        for (h,) in clock.admit((s,), -1 if newest is None else newest):
            one(h)

    def one(s) -> None:
        nonlocal seg, newest, i
        t = s.t_us  # IMU and barometer alike: one clock (a barometer sample of the new boot comes first)
        if newest is not None and (t < newest - CLOCK_BACK_US or t > newest + CLOCK_JUMP_US):
            parts.append(seg.finish(warn))
            tally.add(seg.run.est)
            seg = _Segment(design, cfg, rate_explicit, grid_hz, store_dir, use_c)
            newest = t
        elif newest is None or t > newest:
            newest = t
        seg.push(s, warn)
        if progress is not None and i % 10_000 == 0:
            progress(i)
        i += 1

    for s in samples:
        if type(s) is not SampleRows:
            guard(s)
            continue
        # a run of sensor samples as arrays (postflight/mavlink_log.py): as one by one, but the stretch up
        # to a clock break goes to the C core as it is once the input pipeline passes samples unchanged
        a, n = 0, len(s.t)
        while a < n:
            if newest is None or not seg.rows_ok() or clock.pending:
                guard(ImuSample(int(s.t[a]), *s.v[a].tolist()) if s.kind[a] == 0 else
                      BaroSample(int(s.t[a]), float(s.v[a, 0]), float(s.v[a, 1])))  # fmt: skip
                a += 1
                continue
            t = s.t[a:]
            before = np.maximum.accumulate(np.concatenate(([newest], t[:-1])))  # the newest before each
            cut = np.flatnonzero((t < before - CLOCK_BACK_US) | (t > before + CLOCK_STEP_MAX_US))
            b = a + (int(cut[0]) if len(cut) else n - a)
            if b > a:
                seg.run.feed_rows(s.t[a:b], s.kind[a:b], s.v[a:b])
                newest = max(newest, int(s.t[a:b].max()))
                if progress is not None and (i + b - a) // 10_000 > i // 10_000:
                    progress((i + b - a) // 10_000 * 10_000)
                i += b - a
                a = b
            else:  # off the clock: held (``guard``), one by one
                guard(ImuSample(int(s.t[a]), *s.v[a].tolist()) if s.kind[a] == 0 else
                      BaroSample(int(s.t[a]), float(s.v[a, 0]), float(s.v[a, 1])))  # fmt: skip
                a += 1
    clock.end()  # the log ended before their clock was confirmed
    parts.append(seg.finish(warn))
    tally.add(seg.run.est)
    product = join_segments([p for p in parts if len(p.time_s)], grid_hz)
    product.attrs["design_toml"] = design_toml(design, seg.pipe.cfg)
    product.attrs["north_reference"] = north_reference(design.site.mag_declination_deg)
    product.attrs.update(tally.attrs())
    product.attrs["source_log_samples_rejected"] = tally.rejected  # as loss_attrs names what the log holds
    product.attrs["samples_off_clock"] = clock.glitches
    return product


class _SourceTally:
    """What the estimators of all segments made of the optional sources (the winch, the ground
    reference): used and rejected as implausible, and why the last rejection was."""

    def __init__(self) -> None:
        self.winch = [0, 0, 0]  # used, rejected, the last reason
        self.ground = [0, 0, 0]
        self.rejected = 0  # samples the estimator rejected (``FlightMeta.samples_rejected``: balloon-fw's count)

    def add(self, est: Estimator | None) -> None:
        if est is None:
            return
        self.rejected += int(est.counters.rejected)
        for acc, (used, rejected, reason) in ((self.winch, (est.winch_samples, est.winch_rejected,
                                                            est.winch_reject_reason)),
                                              (self.ground, (est.ground_samples, est.ground_rejected,
                                                             est.ground_reject_reason))):  # fmt: skip
            acc[0] += used
            acc[1] += rejected
            acc[2] = reason or acc[2]

    def attrs(self) -> dict[str, int | str]:
        """The counts as the product's global attributes (integers), and the line the summary and notes say."""
        from firmware_py.estimator.aid_sources import ground_ref, winch

        line = (winch.counts_text("winch", "WINCH_STATUS", *self.winch, winch.REJECT_WORDS) + "; "
                + winch.counts_text("ground reference", "ground reference", *self.ground, ground_ref.REJECT_WORDS))
        return {"winch_status_used": int(self.winch[0]), "winch_status_rejected": int(self.winch[1]),
                "ground_reference_used": int(self.ground[0]), "ground_reference_rejected": int(self.ground[1]),
                "optional_sources": line}  # fmt: skip


def c_core_available() -> bool:
    """Whether the C core's double build can be loaded here (built at first use: a C compiler is needed)."""
    try:
        from firmware_py.core_c import load

        load("double")
    except Exception:  # no compiler, or the build failed: the Python core  # noqa: BLE001
        return False
    return True


class _Segment:
    """One stretch of the log on one sensor clock: its input pipeline, filter and smoother."""

    def __init__(self, design: Design, cfg: FilterConfig, rate_explicit: bool, grid_hz: float,
                 store_dir: str | None, use_c: bool = False) -> None:  # fmt: skip
        self.pipe = InputPipeline(cfg, rate_explicit)
        self.rec = SmootherRecorder(N_STATES, store_dir, cov_states=(WIND_N, WIND_E),
                                    x_states=(POS_N, POS_E, POS_D, WIND_N, WIND_E))  # what the product takes
        self.run = (_CRun if use_c else _Run)(design, self.rec, grid_hz)

    def rows_ok(self) -> bool:
        """Whether sensor samples may go to the filter as arrays (``_CRun.feed_rows``): the C run, its
        estimator made, the input pipeline deciding nothing more and passing samples unchanged."""
        return type(self.run) is _CRun and self.run.est is not None and self.pipe.decided and \
            self.pipe.resampler is None

    def push(self, s: Sample | GroundSample, warn) -> None:
        if type(s) is WinchSample or type(s) is GroundBaroSample:
            self.run.ground(s)
            return
        for t in self.pipe.push(s):
            self.run.feed(self.pipe, t, warn)

    def finish(self, warn) -> WindProduct:
        for t in self.pipe.flush():
            self.run.feed(self.pipe, t, warn)
        run = self.run
        run.finish()
        sm = self.rec.smooth()
        product = _product(sm, np.array(run.modes, np.int8), np.array(run.air).reshape(-1, 2), run.baro_seen,
                           np.array(run.unconfirmed, bool), np.array(run.accuracy, float),
                           np.array(run.inflation, float))  # fmt: skip
        product.consistency_flags = np.array(run.consistency, np.int8)
        product.accuracy_inflation = np.array(run.inflation, float)
        product.flags[np.array(run.after_gap, bool)] |= FLAG_AFTER_GAP
        if run.winch_seen:
            product.line_length_m = np.array(run.line, float)
            product.reel_mps = np.array(run.reel, float)
            product.winch_rejected = np.array(run.rejected, np.int32)
        return product


def join_segments(parts: list[WindProduct], grid_hz: float = GRID_HZ) -> WindProduct:
    """The segments as one product: arrays end to end, ``segment`` numbering them, and ``time_s`` running
    on: a segment whose clock starts before the previous one ended (a reboot) is shifted to begin one grid
    interval after it (``time_since_boot_s`` keeps the sensor clock). One segment: returned as it is."""
    if len(parts) == 1:
        return parts[0]
    if not parts:
        return _product_empty()
    out = {}
    shifted, end = [], -math.inf
    for p in parts:
        shift = max(0.0, end + 1.0 / grid_hz - float(p.time_s[0]))
        shifted.append(p.time_s + shift)
        end = float(shifted[-1][-1])
    for f in dataclasses.fields(WindProduct):
        vals = [getattr(p, f.name) for p in parts]
        if all(isinstance(v, np.ndarray) for v in vals):
            out[f.name] = np.concatenate(vals)
    out["time_s"] = np.concatenate(shifted)
    out["time_since_boot_s"] = np.concatenate([p.time_s for p in parts])
    out["segment"] = np.concatenate([np.full(len(p.time_s), k, np.int16) for k, p in enumerate(parts)])
    joined = WindProduct(**out)
    joined.flags[np.r_[0, np.cumsum([len(p.time_s) for p in parts])[:-1]]] |= FLAG_SEGMENT_START
    return joined


def _product_empty() -> WindProduct:
    z = np.zeros(0)
    return WindProduct(z, z, z, z, z, z, z, z, z, z, z, z, z, z, np.zeros(0, np.int8), np.zeros(0, np.int8))


class _Run:
    """The forward pass: the estimator (built once the input pipeline has chosen the rate), the
    segment bookkeeping, and what the product needs beside the state at each grid point."""

    def __init__(self, design: Design, rec: SmootherRecorder, grid_hz: float) -> None:
        self.design, self.rec, self.grid_hz = design, rec, grid_hz
        self.est: Estimator | None = None
        self.every = 1
        self.sig: tuple = ()
        self.last_grid = 0
        self.baro_seen = False
        self.press = self.temp = math.nan
        self.modes: list[int] = []
        self.unconfirmed: list[bool] = []
        self.air: list[tuple[float, float]] = []
        self.consistency: list[int] = []  # the consistency monitor's flags and accuracy factor (the causal run's)
        self.inflation: list[float] = []
        self.accuracy: list[float] = []  # what the firmware reports (WIND_COV horiz_accuracy)
        self.after_gap: list[bool] = []  # IMU samples were missing since the grid point before
        self._gap = False
        self._prev_us = -1
        self.pending: dict[type, GroundSample] = {}  # from the ground before the estimator exists: the newest
        self.winch_seen = False
        self.line: list[float] = []  # the winch's length and reel speed the filter used at each grid point
        self.reel: list[float] = []
        self.rejected: list[int] = []  # WINCH_STATUS rejected since the grid point before
        self._rejected_before = 0

    def finish(self) -> None:
        """(The C run's blocks end here; this run has none.)"""

    def ground(self, s: GroundSample) -> None:
        """A sample from the ground (the winch, the ground reference): into the estimator as it arrives."""
        if type(s) is WinchSample:
            self.winch_seen = True
        if self.est is None:
            self.pending[type(s)] = s
        else:
            feed_ground(self.est, s)

    def feed(self, pipe: InputPipeline, s: Sample, warn) -> None:
        est = self.est
        if est is None:
            est = self.est = Estimator(self.design, pipe.cfg)
            est.ekf.recorder = self.rec
            for g in self.pending.values():
                feed_ground(est, g)
            self.every = max(1, round(pipe.cfg.imu_rate_hz / self.grid_hz))
            self.sig = _signature(est)
            if pipe.decision.warning and warn is not None:
                warn(pipe.decision.warning)
        if type(s) is BaroSample:
            self.baro_seen = True
            self.press, self.temp = s.pressure_hpa, s.temperature_c
            feed(est, s)
            return
        if self._prev_us >= 0 and s.t_us - self._prev_us > GAP_STEPS * est.dt_us:
            self._gap = True
        self._prev_us = max(self._prev_us, s.t_us)
        advanced = feed(est, s)
        now = _signature(est)
        every = self.every
        if now != self.sig:
            self.rec.broken()
            self.sig = now
            self.last_grid = est.step // every - 1  # a grid point right after the cut starts the segment
        if advanced and est.step // every > self.last_grid:
            self.last_grid = est.step // every
            ekf = est.ekf
            self.rec.grid_point(est.t_last_us, ekf.x, ekf.P)
            self.modes.append(ekf.mode)
            self.unconfirmed.append(est.unconfirmed)
            self.air.append((self.press, self.temp))
            self.consistency.append(est.consistency.flags)
            self.inflation.append(est.consistency.inflation)
            self.accuracy.append(est.wind_accuracy())
            self.after_gap.append(self._gap)
            self._gap = False
            heard = est.winch_samples > 0
            self.line.append(est.model.tether_length_m if heard else math.nan)
            self.reel.append(est.ekf.rope.rate_mps if heard else math.nan)
            self.rejected.append(est.winch_rejected - self._rejected_before)
            self._rejected_before = est.winch_rejected


C_BATCH = 4096  # samples a call of the C core (bw_reprocess_batch)
N_EXTRA = 11  # what a grid point holds beside the state (host/reprocess.c)


class _CRun(_Run):
    """``_Run`` on the C core: the samples the input pipeline passes are handed over in blocks
    (``bw_reprocess_batch``, firmware_c/host/reprocess.c), which runs each as ``_Run.feed`` does, with the
    smoother's recorder in C (include/bw_recorder.h: the same events at the same places as the Python
    core's ``WindEkf.recorder``), makes the grid as ``_Run.feed`` makes it and writes each point straight
    into the ``SmootherRecorder``'s block storage; the backward pass is the recorder's own. A ground
    sample (the winch, the ground reference) runs the samples before it first, so the order is kept."""

    def __init__(self, design: Design, rec: SmootherRecorder, grid_hz: float) -> None:
        super().__init__(design, rec, grid_hz)
        self._t: list[int] = []
        self._kind: list[int] = []
        self._v: list[float] = []
        self._chunks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (feed_rows; before the lists)
        self._pending = 0
        self._extras: list[np.ndarray] = []
        self._extra = np.zeros((BLOCK_C, N_EXTRA))
        self._ng = np.zeros(1, np.int32)
        self._fn = None

    def ground(self, s: GroundSample) -> None:
        if self.est is not None:
            self._run()
        super().ground(s)

    def feed(self, pipe: InputPipeline, s: Sample, warn) -> None:
        if self.est is None:
            import ctypes as C

            from firmware_py.core_c import CEstimator

            est = self.est = CEstimator(self.design, pipe.cfg)  # float32 off: the double build
            for g in self.pending.values():
                feed_ground(est, g)
            self.every = max(1, round(pipe.cfg.imu_rate_hz / self.grid_hz))
            if pipe.decision.warning and warn is not None:
                warn(pipe.decision.warning)
            lib = est._lib
            lib.bw_sizeof_recorder.restype = C.c_size_t
            self._recorder = C.create_string_buffer(lib.bw_sizeof_recorder())
            lib.bw_recorder_init.argtypes = [C.c_void_p, C.c_void_p, C.c_int64]
            lib.bw_recorder_init(self._recorder, C.addressof(est._s), self.every)
            fn = self._fn = lib.bw_reprocess_batch
            fn.argtypes = [C.c_void_p] * 2 + [C.c_int] + [C.c_void_p] * 3 + [C.c_int] + [C.c_void_p] * 9
            fn.restype = C.c_int
        if type(s) is BaroSample:
            self.baro_seen = True
            self._t.append(s.t_us)
            self._kind.append(1)
            self._v.extend((s.pressure_hpa, s.temperature_c, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
        else:
            self._t.append(s.t_us)
            self._kind.append(0)
            self._v.extend(s[1:])
        self._pending += 1
        if self._pending >= C_BATCH:
            self._run()

    def _lists(self) -> None:
        """The samples fed one by one so far as a chunk (before rows that come after them)."""
        if self._t:
            self._chunks.append((np.array(self._t, np.int64), np.array(self._kind, np.int32),
                                 np.array(self._v, np.float64).reshape(-1, 9)))  # fmt: skip
            self._t.clear()
            self._kind.clear()
            self._v.clear()

    def feed_rows(self, t: np.ndarray, kind: np.ndarray, v: np.ndarray) -> None:
        """Sensor samples as arrays (the pipeline passes them unchanged: ``_Segment.rows_ok``), as ``feed``."""
        self._lists()
        if np.any(kind == 1):
            self.baro_seen = True
        self._chunks.append((t, kind, v))
        self._pending += len(t)
        if self._pending >= C_BATCH:
            self._run()

    def _run(self) -> None:
        """The samples handed over so far through the C core, their grid points into the recorder's blocks."""
        self._lists()
        if not self._chunks:
            return
        import ctypes as C

        if len(self._chunks) == 1:
            t, kind, v = self._chunks[0]
        else:
            t, kind, v = (np.concatenate([c[j] for c in self._chunks]) for j in range(3))
        t = np.ascontiguousarray(t, np.int64)
        kind = np.ascontiguousarray(kind, np.int32)
        v = np.ascontiguousarray(v, np.float64)
        self._chunks.clear()
        self._pending = 0
        n = len(t)
        est, rec, start = self.est, self.rec, 0
        N = N_STATES
        while start < n:
            b, k = rec.slots()
            self._ng[0] = 0
            done = self._fn(C.addressof(est._s), self._recorder, n - start, t.ctypes.data + 8 * start,
                            kind.ctypes.data + 4 * start, v.ctypes.data + 72 * start, BLOCK_C - k,
                            self._ng.ctypes.data, b["t"].ctypes.data + 8 * k, b["x"].ctypes.data + 8 * N * k,
                            b["P"].ctypes.data + 8 * N * N * k, b["Pi"].ctypes.data + 8 * N * N * k,
                            b["g"].ctypes.data + 8 * N * k, b["G"].ctypes.data + 8 * N * N * k,
                            b["linked"].ctypes.data + k, self._extra.ctypes.data)  # fmt: skip
            m = int(self._ng[0])
            if m:
                rec.filled(m)
                self._extras.append(self._extra[:m].copy())
            start += done

    def finish(self) -> None:
        """The last samples through the C core; the grid's columns as ``_Run`` keeps them."""
        self._run()
        e = np.concatenate(self._extras) if self._extras else np.zeros((0, N_EXTRA))
        self._extras = []
        self.modes = e[:, 0].astype(np.int8)
        self.unconfirmed = e[:, 1].astype(bool)
        self.consistency = e[:, 2].astype(np.int8)
        self.inflation = e[:, 3].copy()
        self.accuracy = e[:, 4].copy()
        self.after_gap = e[:, 5].astype(bool)
        self.line = e[:, 6].copy()
        self.reel = e[:, 7].copy()
        self.rejected = np.diff(e[:, 8].astype(np.int64), prepend=0).astype(np.int32)
        self.air = e[:, 9:11].copy()


def _unconfirmed_segments(segment_start: np.ndarray, unconfirmed: np.ndarray) -> np.ndarray:
    """A segment that started with a join in flight is a balloon's if the motion confirmed it at any
    time in the segment (smoothing looks both ways); one never confirmed stays unconfirmed throughout."""
    out = unconfirmed.copy()
    starts = [*np.flatnonzero(segment_start), len(out)]
    for a, b in zip(starts[:-1], starts[1:]):
        if out[a:b].any() and not out[a:b].all():
            out[a:b] = False
    return out


# after a taut placement (the entry, a re-placement) the state starts far from the truth and settles over seconds;
# the smoother's chain starts there, linearised about that transient, and its covariance claims more than the
# transient allows (field-rope: the smoothed wind 3.5 sigma off 7-11 s after the entry, where the filter's own stated
# accuracy held it). For this long after such a start the smoothed accuracy is stated no better than the filter's.
TAUT_SETTLE_S = 15.0


def _settling(t_us: np.ndarray, segment_start: np.ndarray, modes: np.ndarray) -> np.ndarray:
    """Where a smoother segment began in the taut mode less than TAUT_SETTLE_S before."""
    out = np.zeros(len(t_us), bool)
    for a in np.flatnonzero(segment_start):  # (n,) bool: Smoothed.segment_start
        if modes[a] == MODE_TAUT:
            out[a : int(np.searchsorted(t_us, t_us[a] + TAUT_SETTLE_S * 1e6))] = True
    return out


def _product(
    sm, modes: np.ndarray, air: np.ndarray, baro_seen: bool, unconfirmed: np.ndarray,
    accuracy: np.ndarray | None = None, inflation: np.ndarray | None = None,
) -> WindProduct:  # fmt: skip
    n = len(sm.t_us)
    var_n = np.maximum(sm.var(WIND_N), 0.0)
    var_e = np.maximum(sm.var(WIND_E), 0.0)
    cvar_n = np.maximum(sm.var(WIND_N, smoothed=False), 0.0)
    cvar_e = np.maximum(sm.var(WIND_E, smoothed=False), 0.0)
    if accuracy is not None and len(accuracy) == n and inflation is not None and len(inflation) == n:
        # the firmware's accuracy holds more than P (Estimator.wind_accuracy): what P cannot know (the
        # drag scale, the rope's Cd; a bias the smoother cannot average away, added) and the consistency
        # monitor's factor (the smoother's model is the filter's: a misfit the filter saw is its too)
        f2 = np.maximum(inflation, 1.0) ** 2
        sys_half = 0.5 * np.maximum(accuracy**2 / f2 - (cvar_n + cvar_e), 0.0)
        keep = unconfirmed  # the join's floor: below, its own rule
        cvar_n = np.where(keep, cvar_n, (cvar_n + sys_half) * f2)
        cvar_e = np.where(keep, cvar_e, (cvar_e + sys_half) * f2)
        var_n = np.where(keep, var_n, (var_n + sys_half) * f2)
        var_e = np.where(keep, var_e, (var_e + sys_half) * f2)
    wn, we = sm.state(WIND_N), sm.state(WIND_E)
    # an unconfirmed join in flight: the reported accuracy is at least sqrt(|w|^2 + 1) (Estimator.wind_accuracy)
    floor_c = 0.5 * (sm.state(WIND_N, False) ** 2 + sm.state(WIND_E, False) ** 2 + 1.0)
    cvar_n = np.where(unconfirmed, np.maximum(cvar_n, floor_c), cvar_n)
    cvar_e = np.where(unconfirmed, np.maximum(cvar_e, floor_c), cvar_e)
    never = _unconfirmed_segments(sm.segment_start, unconfirmed)
    floor_s = 0.5 * (wn**2 + we**2 + 1.0)
    var_n = np.where(never, np.maximum(var_n, floor_s), var_n)
    var_e = np.where(never, np.maximum(var_e, floor_s), var_e)
    settling = _settling(sm.t_us, sm.segment_start, modes)
    var_n = np.where(settling, np.maximum(var_n, cvar_n), var_n)
    var_e = np.where(settling, np.maximum(var_e, cvar_e), var_e)
    flags = np.zeros(n, np.int8)
    flags[sm.segment_start] |= FLAG_SEGMENT_START
    moved = (np.abs(wn - sm.state(WIND_N, False)) > 1e-9) | (np.abs(we - sm.state(WIND_E, False)) > 1e-9)
    flags[moved] |= FLAG_SMOOTHED
    unknown = never | (modes == MODE_GROUND)
    unknown |= wind_unknown(np.hypot(wn, we), np.sqrt(var_n + var_e))
    flags[unknown] |= FLAG_WIND_UNKNOWN
    height = -sm.state(POS_D)
    if not baro_seen:
        flags |= FLAG_NO_BARO
        height = np.full(n, np.nan)
    return WindProduct(
        time_s=sm.t_us * 1e-6,
        wind_n=wn.copy(),
        wind_e=we.copy(),
        sigma_n=np.sqrt(var_n),
        sigma_e=np.sqrt(var_e),
        causal_n=sm.state(WIND_N, False).copy(),
        causal_e=sm.state(WIND_E, False).copy(),
        causal_sigma_n=np.sqrt(cvar_n),
        causal_sigma_e=np.sqrt(cvar_e),
        height_m=height,
        pos_n=sm.state(POS_N).copy(),
        pos_e=sm.state(POS_E).copy(),
        air_pressure_pa=air[:, 0] * 100.0 if n else np.zeros(0),
        air_temperature_k=air[:, 1] + 273.15 if n else np.zeros(0),
        mode=modes,
        flags=flags,
    )


def run_reprocess(args, argv: list[str] | None) -> int:
    """``balloon-gs reprocess FLIGHT --out FILE.nc [--config] [--plot] [--quiet]``."""
    import shlex

    from balloon_core.atomic import Products, sigterm_raises
    from balloon_core.userargs import ctrl_c_raises, require_extra

    require_extra("postflight")  # before any work: a missing extra is one line, exit 2
    sigterm_raises()  # SIGTERM ends the run like Ctrl-C: its temporary files are removed
    ctrl_c_raises()

    from balloon_core.config import ConfigError, design_from_dict, load_toml
    from balloon_core.progress import Progress
    from postflight.logs import read_flight
    from postflight.netcdf import write_products

    prog = "balloon-gs reprocess"
    if not args.out.endswith(".nc"):
        raise ValueError(f"--out {args.out}: the product is NetCDF, its name must end in .nc")
    if args.plot:
        from matplotlib.backend_bases import FigureCanvasBase

        kinds = FigureCanvasBase.get_supported_filetypes()
        if os.path.splitext(args.plot)[1].lower().lstrip(".") not in kinds:
            raise ValueError(f"--plot {args.plot}: the name must end in one of .{', .'.join(sorted(kinds))}")
    try:
        data = load_toml(args.config) if args.config else {}
        design = design_from_dict(data)
        cfg = FilterConfig.from_dict(data.get("filter", {}))
    except ConfigError as exc:
        raise ValueError(str(exc)) from None
    given = f"from {os.path.basename(args.config)}" if args.config else "the defaults (no --config given)"
    other = {name: values for name, values in data.items() if name not in ("balloon", "tether", "site", "sensors",
                                                                           "filter")}  # fmt: skip
    t0 = time.perf_counter()
    bar = Progress(prog, unit="", quiet=args.quiet)
    bar.update(status=f"reading {os.path.basename(args.flight)}")
    try:
        flight = read_flight(args.flight)
        meta = flight.meta
        if getattr(args, "ground_pressure", None):
            flight, note = _with_ground_csv(flight, args.ground_pressure)
            meta.notes.append(note)
        bar.log(f"{prog}: {meta.describe()}")
        for note in meta.notes:
            bar.log(f"{prog}: note: {note}")
        bar.total, bar.unit = float(len(flight)), "samples"
        flight.release()  # (its kinds and times: meta holds what they told; the samples come from the file)
        with tempfile.TemporaryDirectory(prefix="balloon-reprocess-") as store:  # the smoother's store spills here
            product = reprocess(flight.blocks(), design, cfg, rate_explicit="imu_rate_hz" in data.get("filter", {}),
                                progress=lambda n: bar.update(n, "forward filter"),
                                warn=lambda w: bar.log(f"{prog}: {w}"), store_dir=store)  # fmt: skip
        bar.update(len(flight), "smoother done; writing the products")
        if len(product.time_s) == 0:
            raise ValueError(f"{args.flight}: the estimator never started (no IMU + magnetometer sample with zacc < 0)")
        product.utc_start_s = meta.utc_start_s
        meta.samples_rejected = int(product.attrs.get("source_log_samples_rejected", 0))
        rejected = rejected_note(meta)
        if rejected:
            meta.notes.append(rejected)
        meta.notes.append(product.attrs["optional_sources"])
        bar.log(f"{prog}: {product.attrs['optional_sources']}")
        product.attrs.update({
            "design_toml": f"# {given}\n" + product.attrs["design_toml"] + (to_toml(other, "")[1:] if other else ""),
            "source_log": meta.source,
            "source_log_sha256": meta.sha256,
            "source_log_format": meta.format,
            "source_log_sensors": ", ".join(f"{k}: {v}" for k, v in meta.sensors.items()),
            **loss_attrs(meta, product),
        })  # fmt: skip
        words = argv if argv is not None else sys.argv[1:]
        history = "balloon-gs " + " ".join(shlex.quote(a) for a in words)
        with Products() as products:  # every product under a temporary name, all renamed when all are written
            paths = write_products(product, args.out, args.plot, history, products)
            paths += _write_profile(product, args.out, args.plot, history, products)
            products.commit()
    finally:
        bar.close()
    if loss_notes(meta) or segment_note(meta) or not args.quiet:  # a loss is told under --quiet too
        print(f"{prog}: {loss_line(meta)}", file=sys.stderr)
    if rejected_note(meta):  # under --quiet too, as a note: it counts more than damaged values
        print(f"{prog}: note: {meta.source}: {rejected_note(meta)}", file=sys.stderr)
    print(_summary(product, meta, time.perf_counter() - t0))
    print("wrote " + ", ".join(paths))
    return 0


def loss_attrs(meta, product: WindProduct) -> dict[str, int | str]:
    """What the log lost, as the product's global attributes (each counted once, by the reader; counts as integers)."""
    segments = 1 if product.segment is None else int(product.segment.max()) + 1
    return {
        "source_log_bad_frames": int(meta.bad_frames),
        "source_log_truncated": "yes" if meta.truncated else "no",
        "source_log_imu_samples_missing": int(meta.imu_missing),
        "source_log_samples_rejected": int(meta.samples_rejected),
        "source_log_gaps": int(meta.gaps),
        "source_log_segments": segments,
        "source_log_losses": loss_line(meta),
        "source_log_notes": "; ".join(meta.notes) if meta.notes else "none",
    }


def loss_line(meta) -> str:
    """One line: what the flight file lost, or that it lost nothing."""
    notes = loss_notes(meta)
    seg = segment_note(meta)
    head = "DATA LOST: " + "; ".join(notes) if notes else "nothing lost (0 bad frames, 0 IMU samples missing)"
    return f"{meta.source}: {head}" + (f"; {seg}" if seg else "")


def _with_ground_csv(flight, path: str):
    """(the flight with the ground reference of a ``--ground-pressure`` CSV (balloon_core/groundref.py)
    merged in by time, the note that says so): on the sensor clock (``time_s``) as it is, UNIX time
    (``time_unix_s``) through the log's UTC. The file is checked whole first (its time in order), then read again
    as the flight is (a stream: memory flat in its length); it is only read, never written. Readings that miss the
    flight's time altogether are an error (as ``balloon-gs report`` refuses a truth that does not overlap the
    estimates)."""
    from balloon_core.groundref import ground_rows, scan_ground_csv

    tcol, n = scan_ground_csv(path)
    shift = 0.0
    if tcol == "time_unix_s":
        if flight.meta.utc_start_s is None:
            raise ValueError(f"{path}: time_unix_s needs the log's UTC, and {flight.meta.source} has none: "
                             "give time_s on the sensor clock")  # fmt: skip
        shift = flight.meta.utc_start_s

    def rows():
        for t, p, temp in ground_rows(path)[1]:
            yield round((t - shift) * 1e6), p, temp

    if flight.t_us is not None and len(flight.t_us):
        lo, hi = int(flight.t_us.min()), int(flight.t_us.max())
        first = last = None
        for t, _, _ in rows():
            first = t if first is None else first
            last = t
        if last < lo or first > hi:  # in time order (scan_ground_csv): all before the flight, or all after it
            raise ValueError(f"{path}: the ground readings ({first * 1e-6:.1f}-{last * 1e-6:.1f} s on the sensor "
                             f"clock) do not overlap the flight ({lo * 1e-6:.1f}-{hi * 1e-6:.1f} s): is it this "
                             "flight's ground reference?")  # fmt: skip
    return flight.with_ground_rows(rows), f"ground reference from {os.path.basename(path)} ({n} readings)"


def _write_profile(product: WindProduct, out: str, plot: str | None, history: str, products) -> list[str]:
    """With winch legs: ``<out stem>_profile.nc`` (CF featureType profile) and, with ``--plot``, the
    profile's plot beside the product's (``<plot stem>_profile<ext>``)."""
    from postflight.profile import plot_profile, wind_profile, write_profile

    prof = wind_profile(product)
    if prof is None:
        return []
    stem = os.path.splitext(out)[0]
    paths = [f"{stem}_profile.nc"]
    write_profile(prof, product, products.path(paths[0]), history)
    if plot:
        base, ext = os.path.splitext(plot)
        paths.append(f"{base}_profile{ext}")
        plot_profile(prof, products.path(paths[-1]))
    print(f"profile: {len(prof.legs)} legs, power-law exponent {prof.alpha:.3f} +- {prof.sigma_alpha:.3f}, "
          f"veer {prof.veer_deg_100m:+.1f} +- {prof.sigma_veer_deg_100m:.1f} deg per 100 m")  # fmt: skip
    return paths


MISFIT_DOUBT_SHARE = 0.5  # the consistency monitor flagged more of the flight than this: the summary doubts the design


def _summary(p: WindProduct, meta, wall_s: float) -> str:
    known = (p.flags & FLAG_WIND_UNKNOWN) == 0
    segments = int(np.count_nonzero(p.flags & FLAG_SEGMENT_START))
    if np.any(known):
        sp = float(np.hypot(np.mean(p.wind_n[known]), np.mean(p.wind_e[known])))
        acc = float(np.median(np.hypot(p.sigma_n[known], p.sigma_e[known])))
        frm = direction_from_deg(np.mean(p.wind_n[known]), np.mean(p.wind_e[known]))
        wind = f"mean wind {sp:.2f} m/s from {frm:03.0f} deg, median accuracy {acc:.2f} m/s over {known.mean():.0%}"
    else:
        wind = "the wind is NOT known anywhere in this flight (accuracy too poor: not a tethered balloon?)"
    baro = "" if meta.has_baro else ", NO barometer: height unknown"
    log_segments = 1 if p.segment is None else int(p.segment.max()) + 1
    misfit = float(np.mean(p.consistency_flags != 0)) if p.consistency_flags is not None else 0.0
    # most of the flight unexplained: the first thing to doubt is the design the log was reprocessed with
    doubt = (f"; the model did not explain the data {misfit:.0%} of the time (consistency_flags): is the design "
             f"(--config) this flight's?") if misfit > MISFIT_DOUBT_SHARE else ""  # fmt: skip
    return (f"{meta.source}: {len(p.time_s)} estimates over {p.time_s[-1] - p.time_s[0]:.0f} s, {log_segments} log "
            f"segment{'s' if log_segments != 1 else ''}, {segments} smoother segments, "
            f"{wind}{baro}{doubt}; {wall_s:.1f} s")  # fmt: skip
