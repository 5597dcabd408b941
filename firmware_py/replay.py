"""``balloon-fw``'s file replay of a tlog on the C core, with the host library's tlog scanner
(firmware_c/host/tlog.c, ``bw_tlog_scan``): the records framed and checked in C, and the common sensor
frames (the IMU's HIGHRES_IMU, the balloon's SCALED_PRESSURE, each the next packet of its sender) taken
through what the firmware does with them (``LinkStats.sequence``, ``MavlinkSampler.convert``,
``Firmware.push`` with the rate decided and no averaging) straight into a sample block, without a Python
message each. When an output may be due the scanner runs the block through the C core (``bw_on_batch``)
and, in the usual case (the block in one piece ending on a filter step; no STATUSTEXT, HEARTBEAT or WIND
due with it), counts its steps and packs its WIND_COV (as pymavlink packs it) itself. Every other frame
(other messages, anything unusual: a lost or late packet, a new sender, a time going back, the rate still
being measured) and every other output comes back here in file order and goes the ordinary way
(``Decoder.decode_frame``: fastmav or pymavlink, then ``Firmware.handle``; ``Firmware.run_block`` from
where the C core stopped), so the outputs, their bytes and every count are those of the Python path
(tests/unit/test_replay_scan.py).

The Python objects hold the state: it is copied into the scanner's state array before a call and back
after it (``_Lane``). Without the C core's library (or without fastcrc: no fast decoding either)
``scanner()`` is None and the caller replays the ordinary way."""

from __future__ import annotations

import ctypes as C
from collections.abc import Callable

import numpy as np

from balloon_core import fastmav
from balloon_core.wire import TLOG_HEADER, Decoder, LinkStats, SenderSeq
from firmware_py.app import BATCH_SAMPLES, Firmware
from firmware_py.core_c import SampleBlock
from firmware_py.estimator.consistency import SOURCES
from firmware_py.estimator.state import MODE_GROUND

WIND_COV = fastmav.mavlink.MAVLink_wind_cov_message

# the state array's fields (firmware_c/host/tlog.c)
(S_I, S_N, S_EOF, S_LANE, S_J, S_END, S_BYTES, S_FRAMES, S_GARBAGE, S_BAD, S_TRUNC, S_IMU_MID, S_IMU_SYS,
 S_IMU_COMP, S_IMU_ID, S_HAVE_IMU, S_EMBEDDED, S_OTHERS, S_IGNORED, S_BESIDE, S_HAVE_BARO, S_BARO_MID,
 S_BARO_SYS, S_BARO_COMP, S_GROUND, S_SAMPLES, S_MISSING, S_PREV, S_BLOCK_T, S_DT, S_NEXT_WIND, S_NEXT_HB,
 S_LEN, S_BATCH, S_ROWS, S_RECENT, S_NSEND, S_EMIT, S_TOLD, S_NEXT_TEXT, S_SENT, S_SEQ, S_SYSID, S_COMPID,
 S_PERIOD, S_MSG_ID, S_MSG_EXTRA, S_GROUND_MODE, S_NSRC, S_LAST_STEP, S_FLIGHT, S_MISFIT) = range(52)  # fmt: skip
S_NOUT, S_DONE, S_SINCE = S_MISFIT + 8, S_MISFIT + 9, S_MISFIT + 10  # S_SINCE: 3 (MavlinkSampler.repeat_since)
S_SENDERS, Q_SIZE, MAX_SENDERS = 80, 16, 16
R_MORE, R_END, R_FRAME, R_DRAIN, R_BATCHED, R_OUT = range(6)
OUT_CAP, OUT_SLOT = 64, 64
CHUNK = 1 << 20


class Scanner:
    """``bw_tlog_scan`` of the host library the firmware's estimator is built in (it runs the block
    through that estimator): ``scan(est, buf, *pointers)``."""

    def __init__(self) -> None:
        self._fns: dict = {}

    def __call__(self, est, buf: bytes, *ptrs) -> int:
        f = self._fns.get(id(est._lib))
        if f is None:
            f = est._lib.bw_tlog_scan
            f.argtypes = [C.c_char_p] + [C.c_void_p] * 13
            f.restype = C.c_int
            self._fns[id(est._lib)] = f
        return f(buf, *ptrs)


def scanner() -> Scanner | None:
    """The tlog scanner, or None where there is none (no C compiler) or no fast decoding (no fastcrc)."""
    if not fastmav.TABLE:
        return None
    try:
        from firmware_py.core_c import load

        load("double")
    except Exception:  # no C core on this host: the ordinary path
        return None
    return Scanner()


def sampler_to_scanner(s, v: list, D: np.ndarray) -> None:
    """What the scanner reads of a ``MavlinkSampler`` (the chosen IMU, its barometer and the ground station; the
    thermometer's and the sensors' last readings and since when they repeat), into ``v`` (the head of S) and ``D``:
    the one place the sampler's state crosses to C (the replay's lane and postflight's log reader alike)."""
    v[S_IMU_MID], v[S_IMU_SYS], v[S_IMU_COMP], v[S_IMU_ID] = s.imu_key
    v[S_HAVE_IMU] = 1
    v[S_EMBEDDED], v[S_OTHERS] = s.embedded_baro, s._others
    if s.baro_key is not None:
        v[S_HAVE_BARO] = 1
        v[S_BARO_MID], v[S_BARO_SYS], v[S_BARO_COMP] = s.baro_key[:3]
    v[S_GROUND] = s.ground_sysid if s.ground_sysid is not None else -1
    v[S_SINCE : S_SINCE + 3] = s.repeat_since
    D[0] = s._last_temp_c
    D[1:10] = s.last_readings


def sampler_from_scanner(s, v: list, D: np.ndarray) -> None:
    """What the scanner changed of the sampler's state (``sampler_to_scanner``), back into it."""
    s.embedded_baro, s._others = bool(v[S_EMBEDDED]), v[S_OTHERS]
    s.baro_beside += v[S_BESIDE]
    s._last_temp_c = float(D[0])
    s.last_readings[:] = D[1:10].tolist()
    s.repeat_since[:] = v[S_SINCE : S_SINCE + 3]


def senders_to_scanner(stats, v: list) -> list:
    """Each sender's sequence record (at most MAX_SENDERS), appended to ``v`` as the scanner reads them; the records in
    that order (``senders_from_scanner`` puts them back)."""
    senders = []
    for (sys, comp), q in stats.senders.items():
        if len(senders) == MAX_SENDERS:
            break
        senders.append(q)
        v += (sys, comp, q.received, q._newest, q._behind, q._t0, q._i0, q._t_mid, q._i_mid, q._t_last,
              q._i_last, not q._holes, 0, 0, 0, 0)  # fmt: skip
    v[S_NSEND] = len(senders)
    return senders


def senders_from_scanner(senders: list, S: np.ndarray) -> None:
    """The senders' sequence records as the scanner left them (``senders_to_scanner``'s order)."""
    k = S_SENDERS
    for q in senders:
        (q.received, q._newest, q._behind, q._t0, q._i0, q._t_mid, q._i_mid, q._t_last,
         q._i_last) = S[k + 2 : k + 11].tolist()  # fmt: skip
        k += Q_SIZE


class _Lane:
    """The scanner's arrays, and the firmware's state copied into them (``load``) and back (``store``)."""

    def __init__(self, fw: Firmware) -> None:
        self.fw = fw
        self.S = np.zeros(S_SENDERS + Q_SIZE * MAX_SENDERS, np.int64)
        self.D = np.zeros(10)  # the last thermometer reading, then MavlinkSampler.last_readings
        # the samples the scanner takes, written in C straight into a block of their own (``rows``)
        self.blk = blk = SampleBlock(BATCH_SAMPLES + 2)
        self.recent = np.zeros(BATCH_SAMPLES + 2, np.int64)
        self.out = np.zeros(OUT_CAP * OUT_SLOT, np.uint8)  # WIND_COV frames packed in C, and (time, length)
        self.out_meta = np.zeros(2 * OUT_CAP, np.int64)
        self.ptrs = [self.S.ctypes.data, self.D.ctypes.data, blk.t_p, blk.kind_p, blk.v_p, self.recent.ctypes.data,
                     0, blk.stepped_p, blk.steps_p, blk.modes_p, blk.flags_p, self.out.ctypes.data,
                     self.out_meta.ctypes.data]  # fmt: skip
        self.senders: list[SenderSeq] = []
        self.dirty = True  # the firmware's state is to be copied in before the next scan

    def load(self, i: int, n: int, eof: bool) -> None:
        """The buffer, and the firmware's state if Python may have changed it since the last scan (``dirty``:
        a frame handled the ordinary way, the status read); after a drain only what a drain changes."""
        fw, S = self.fw, self.S
        if not self.dirty:  # (what a drain may change)
            S[S_I], S[S_N], S[S_EOF] = i, n, eof
            S[S_LEN], S[S_NEXT_WIND], S[S_NEXT_HB] = len(fw._block) + S[S_ROWS], fw._next_wind_us, fw._next_hb_us
            S[S_TOLD], S[S_NEXT_TEXT], S[S_SENT], S[S_SEQ] = (fw._told_flags, fw._next_text_us, fw.wind_cov_sent,
                                                              fw.mav.seq)  # fmt: skip
            S[S_LAST_STEP] = fw._last_step
            return
        self.dirty = False
        s = fw.sampler
        lane = (fw._block is not None and fw.pipe.decided and fw.pipe.resampler is None and fw.streams is None
                and s.imu_key is not None and s.imu_key[0] == fastmav.mavlink.MAVLINK_MSG_ID_HIGHRES_IMU
                and not fw.clock.pending)  # fmt: skip
        self.senders = []
        self.take_rows()  # (none: what Python changed came after the last rows were handed over)
        if not lane:
            S[:S_SENDERS] = 0
            S[S_I], S[S_N], S[S_EOF] = i, n, eof
            return
        v = [0] * S_SENDERS
        v[S_I], v[S_N], v[S_EOF], v[S_LANE] = i, n, eof, 1
        sampler_to_scanner(s, v, self.D)
        v[S_MISSING], v[S_PREV], v[S_BLOCK_T], v[S_DT] = fw.imu_missing, fw._prev_imu_us, fw._block_t_us, fw.est.dt_us
        v[S_NEXT_WIND], v[S_NEXT_HB] = fw._next_wind_us, fw._next_hb_us
        v[S_LEN], v[S_BATCH] = len(fw._block), BATCH_SAMPLES
        self.senders = senders_to_scanner(fw.stats, v)
        # the outputs: the usual WIND_COV packed in C unless a signing link or WIND after each one
        v[S_EMIT] = not fw.wind_after_each and not fw.mav.signing.sign_outgoing
        v[S_TOLD], v[S_NEXT_TEXT], v[S_SENT], v[S_SEQ] = fw._told_flags, fw._next_text_us, fw.wind_cov_sent, fw.mav.seq
        v[S_SYSID], v[S_COMPID], v[S_PERIOD] = fw.mav.srcSystem, fw.mav.srcComponent, fw.period_us
        v[S_MSG_ID], v[S_MSG_EXTRA] = WIND_COV.id, WIND_COV.crc_extra
        v[S_GROUND_MODE], v[S_NSRC], v[S_LAST_STEP] = MODE_GROUND, len(SOURCES), fw._last_step
        S[: len(v)] = v
        self.ptrs[6] = C.addressof(fw.est._s)  # the estimator the scanner runs the block through

    def take_rows(self) -> None:
        """The scanner's samples not yet run into the firmware's block (before Python adds its own)."""
        rows = int(self.S[S_ROWS])
        if rows:
            blk, lb = self.fw._block, self.blk
            blk._t.extend(lb.t[:rows].tolist())
            blk._kind.extend(lb.kind[:rows].tolist())
            blk._v.extend(lb.v.reshape(-1)[: 9 * rows].tolist())
            self.S[S_ROWS] = 0

    def drain(self, done: int = 0) -> None:
        """``Firmware.drain`` with the scanner's samples: run from its own block when they are all there are
        (``done``: its first piece was run in C)."""
        fw = self.fw
        rows = int(self.S[S_ROWS])
        if rows and not len(fw._block):
            self.blk.n = rows
            fw.run_block(self.blk, done)
            self.S[S_ROWS] = 0
        else:
            assert not done
            self.take_rows()
            fw.drain()

    def store(self) -> None:
        """What the scanner did, into the firmware's objects."""
        fw, S = self.fw, self.S
        st = fw.stats
        v = S[:S_SENDERS].tolist()
        st.bytes += v[S_BYTES]
        st.frames += v[S_FRAMES]
        st.garbage_bytes += v[S_GARBAGE]
        st.bad_frames += v[S_BAD]
        if v[S_TRUNC]:
            st.truncated = True
        if not v[S_LANE] or not v[S_FRAMES]:
            return
        sampler_from_scanner(fw.sampler, v, self.D)
        if v[S_SAMPLES]:
            fw.silent = False
            fw.samples_in += v[S_SAMPLES]
            fw.imu_missing, fw._prev_imu_us, fw._block_t_us = v[S_MISSING], v[S_PREV], v[S_BLOCK_T]
            fw._recent_imu_us.extend(self.recent[: v[S_RECENT]].tolist())
        senders_from_scanner(self.senders, S)
        # the blocks run in C (``run_rows`` in tlog.c): their step counts and WIND_COV frames
        if v[S_FLIGHT]:
            fw.flight_steps += v[S_FLIGHT]
        misfit = v[S_MISFIT : S_MISFIT + len(SOURCES)]
        if any(misfit):
            for i, d in enumerate(misfit):
                fw.misfit_steps[i] += d
        fw._last_step, fw._next_wind_us = v[S_LAST_STEP], v[S_NEXT_WIND]
        nout = v[S_NOUT]
        if nout:
            fw.wind_cov_sent, fw.mav.seq = v[S_SENT], v[S_SEQ]
            fw.mav.total_packets_sent += nout
            meta, out = self.out_meta[: 2 * nout].tolist(), self.out
            for k in range(nout):
                fw._send(out[OUT_SLOT * k : OUT_SLOT * k + meta[2 * k + 1]].tobytes(), meta[2 * k])


def replay_tlog(fw: Firmware, path: str, scan, progress=None, stop: Callable[[], bool] | None = None,
                chunk: int = CHUNK) -> bool:  # fmt: skip
    """Every record of the tlog at ``path`` through ``fw`` (``scan``: ``scanner()``), as
    ``wire.tlog_messages`` + ``Firmware.handle`` would; the file is read ``chunk`` bytes at a time.
    About every 1000 frames ``stop()`` is asked and ``progress`` told. Returns False if ``stop()`` said
    to stop. The caller flushes."""
    st: LinkStats = fw.stats
    dec = Decoder(st, fast=True)
    lane = _Lane(fw)
    S = lane.S
    p = lane.ptrs
    next_tick = 1000
    with open(path, "rb") as fh:
        buf, i, eof = b"", 0, False
        while True:
            lane.load(i, len(buf), eof)
            r = scan(fw.est, buf, *p)
            lane.store()
            i = int(S[S_I])
            if r == R_MORE:
                if eof:  # (the scanner says R_END there)
                    lane.take_rows()
                    break
                more = fh.read(chunk)
                buf, i, eof = buf[i:] + more, 0, not more
                continue
            if r == R_END:
                lane.take_rows()  # the caller's flush runs them
                break
            if r == R_FRAME:
                lane.take_rows()
                j, i = int(S[S_J]), int(S[S_END])
                m = dec.decode_frame(buf[j:i])
                if m is not None:
                    fw.handle(m)
                lane.dirty = True
            elif r == R_DRAIN:
                lane.drain()
            elif r == R_BATCHED:
                lane.drain(int(S[S_DONE]))
            seen = st.frames + st.bad_frames
            if seen >= next_tick:
                next_tick = seen + 1000
                if stop is not None and stop():
                    lane.take_rows()  # what was read counts in the summary
                    return False
                if progress is not None:
                    lane.take_rows()
                    lane.dirty = True  # fw.status() runs what waits
                    progress.done = (st.bytes + st.garbage_bytes + TLOG_HEADER * seen) / 1e6
                    progress.status = fw.status()
    return True
