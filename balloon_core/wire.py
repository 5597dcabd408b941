"""MAVLink I/O at the program's edge: endpoints (tlog / raw capture / UDP / serial) to decoded
messages, and sinks (tlog / UDP). Parsing is pymavlink's (a replay's sensor messages: ``fastmav``'s, which
takes only what pymavlink takes alike); bad frames are counted, never raised."""

from __future__ import annotations

import errno
import itertools
import socket
import struct
import time
from collections import deque
from collections.abc import Iterable, Iterator
from typing import BinaryIO, TypeVar

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core import fastmav
from balloon_core.samples import MAX_TIME_US

TLOG_HEADER = 8
MAGIC_V2, MAGIC_V1 = 0xFD, 0xFE
MAGICS = (MAGIC_V2, MAGIC_V1)
CLOCK_BACK_US = 1_000_000  # a sender's clock going back further than this restarted (less: a late packet)
MAX_CLOCK_STEP_US = 86_400_000_000  # a sender's clock stepping further than a day is not its boot clock
MAX_FRAME = 280  # the longest MAVLink 2 frame: 10 header + 255 payload + 2 CRC + 13 signature
# a tlog record's time (its 8-byte header: no CRC covers it) further than this from the last plausible one is held
# until the records after it decide (``plausible_record_times``): RECORD_CONFIRM of them near it confirm it (a
# recording resumed after a pause, two logs end to end); one near the old clock, or none near it among the next
# RECORD_LOOKAHEAD records (or before the file ends), says it is damaged. 10 s: one damaged byte of the time's
# upper four (big-endian microseconds) moves it at least 2^24 us (16.8 s); a real pause is confirmed by what follows
RECORD_JUMP_S = 10.0
RECORD_CONFIRM = 2
RECORD_LOOKAHEAD = 16


def pack(mav, msg) -> bytes:
    """Encode ``msg`` as the next frame of ``mav``'s stream. ``MAVLink.pack`` alone does not advance the
    sequence number (``MAVLink.send`` does), and receivers count lost packets from it."""
    frame = msg.pack(mav)
    mav.seq = (mav.seq + 1) % 256
    mav.total_packets_sent += 1
    return frame


class FastPacker:
    """``pack(mav, cls(*fields))`` for one message class (no arrays) without building the message: the
    firmware's 10 Hz WIND_COV. The same bytes as pymavlink's (MAVLink 2, trailing zero bytes cut, CRC with
    CRC_EXTRA) and the same sequence step; a signing link, or no fastcrc, goes through pymavlink."""

    HEAD = struct.Struct("<BBBBBBBHB")
    CRC = struct.Struct("<H")

    def __init__(self, cls) -> None:
        self.cls = cls
        self.payload = cls.unpacker
        self.extra = bytes((cls.crc_extra,))
        self.id_lo, self.id_hi = cls.id & 0xFFFF, cls.id >> 16

    def __call__(self, mav, *fields) -> bytes:
        if fastmav.mcrf4xx is None or mav.signing.sign_outgoing:
            return pack(mav, self.cls(*fields))
        payload = self.payload.pack(*fields).rstrip(b"\0") or b"\0"  # pymavlink keeps at least one byte
        head = self.HEAD.pack(MAGIC_V2, len(payload), 0, 0, mav.seq, mav.srcSystem, mav.srcComponent, self.id_lo,
                              self.id_hi)  # fmt: skip
        crc = fastmav.mcrf4xx(self.extra, fastmav.mcrf4xx(payload, fastmav.mcrf4xx(head[1:], fastmav.CRC_INIT)))
        mav.seq = (mav.seq + 1) % 256
        mav.total_packets_sent += 1
        return head + payload + self.CRC.pack(crc)


class SenderSeq:
    """One sender's (system, component) MAVLink sequence numbers: packets received, lost, late and
    duplicated. The 8-bit sequence is unwrapped into a packet index: a packet up to 127 ahead of the
    newest is new (the ones skipped are counted lost), one up to 128 behind is late. A late packet that
    fills a hole within the last 128 is "reordered" and no longer lost; any other late one is a
    duplicate. A run of RESYNC_AFTER such packets in a row is a sender that restarted: follow it.

    A silence longer than a sequence cycle wraps the 8-bit counter unseen: when a packet carries the
    sender's own clock (``time_usec`` / ``time_boot_ms``) and that clock jumped by more than half a
    cycle's worth of packets (at the sender's packet rate, measured from its stream), the whole cycles
    the sequence cannot show are added to the lost count (``see_timed``)."""

    __slots__ = ("received", "lost", "reordered", "duplicates", "restarts", "_newest", "_holes", "_behind",
                 "_t0", "_i0", "_t_mid", "_i_mid", "_t_last", "_i_last")  # fmt: skip
    WINDOW = 128
    RESYNC_AFTER = 4
    CYCLE = 256
    RATE_MIN_S = 1.0  # the packet rate is known once the sender's clock has run this long
    RATE_SPAN_S = 10.0  # ... and measured over about the last this long (a stream that speeds up or slows)

    def __init__(self) -> None:
        self.received = self.lost = self.reordered = self.duplicates = self.restarts = 0
        self._newest = -1  # unwrapped index of the newest packet
        self._holes: deque[int] = deque()  # unwrapped indices counted lost, ascending, within WINDOW
        self._behind = 0
        # the sender's clock (us) at the rate's anchor, at the next anchor and at the last timed packet
        self._t0 = self._t_mid = self._t_last = -1
        self._i0 = self._i_mid = self._i_last = 0  # the packet indices there

    def see_timed(self, seq: int, t_us: int) -> int:
        """``see`` for a packet that carries the sender's clock ``t_us``. After a silence longer than half
        the sequence window (at the sender's recent packet rate) the 8-bit number cannot tell how many
        cycles went by: the packet gets the index that its number allows nearest to where the clock says
        the sender is, and what lies between is lost (the packets of the run ``see`` took for late
        copies were new ones). Returns the change in the lost count."""
        t_last = self._t_last
        if t_last < 0 or t_us < t_last - CLOCK_BACK_US or t_us - t_last > MAX_CLOCK_STEP_US:  # first, or a restart
            lost = self.see(seq)
            self._t0 = self._t_mid = self._t_last = t_us
            self._i0 = self._i_mid = self._i_last = self._newest
            return lost
        span = t_last - self._t0
        if span >= self.RATE_MIN_S * 1e6 and self._i_last > self._i0:
            expected = self._i_last + (t_us - t_last) * (self._i_last - self._i0) / span
            newest = self._newest
            if expected - newest > self.WINDOW / 2:
                index = newest + 1 + (seq - newest - 1) % self.CYCLE  # the first index this number allows
                index += self.CYCLE * max(0, round((expected - index) / self.CYCLE))
                lost = index - newest - 1 - self._behind
                self.duplicates -= self._behind
                self.received += 1
                self.lost += lost
                self._newest = index
                self._holes.clear()
                self._behind = 0
                self._t_last, self._i_last = t_us, index
                return lost
        lost = self.see(seq)
        if lost >= 0 and self._behind == 0 and t_us >= t_last:  # a new packet: the clock's anchor moves on
            if t_us - self._t_mid > self.RATE_SPAN_S * 1e6:  # the rate over the last 1-2 RATE_SPAN_S
                self._t0, self._i0 = self._t_mid, self._i_mid
                self._t_mid, self._i_mid = self._t_last, self._i_last
            self._t_last, self._i_last = t_us, self._newest
        return lost

    def see(self, seq: int) -> int:
        """Account for one packet; returns the change in the lost count (+n for a hole, -1 when a late
        packet fills one)."""
        self.received += 1
        newest = self._newest
        if newest < 0:
            self._newest = seq
            return 0
        ahead = (seq - newest) % 256
        if ahead == 1:  # the usual case
            self._newest = newest + 1
            self._behind = 0
            holes = self._holes
            while holes and holes[0] <= newest + 1 - self.WINDOW:
                holes.popleft()
            return 0
        if 0 < ahead < self.WINDOW:
            holes = self._holes
            holes.extend(range(newest + 1, newest + ahead))
            self._newest = newest = newest + ahead
            while holes and holes[0] <= newest - self.WINDOW:
                holes.popleft()
            self._behind = 0
            self.lost += ahead - 1
            return ahead - 1
        index = newest - (256 - ahead) % 256  # ahead == 0 or >= WINDOW: this or an earlier packet again
        if index in self._holes:
            self._holes.remove(index)
            self.reordered += 1
            self.lost -= 1
            self._behind = 0
            return -1
        self.duplicates += 1
        self._behind += 1
        if self._behind >= self.RESYNC_AFTER:  # not a stray copy: the sender started again
            self.restarts += 1
            self.duplicates -= self.RESYNC_AFTER  # they were the restarted sender's new packets
            self._newest = newest + 256 + (seq - newest) % 256  # a fresh index range (index = seq mod 256)
            self._holes.clear()
            self._behind = 0
        return 0


class LinkStats:
    """What came over one link: bytes, frames, corrupt frames, garbage, and per sender (system,
    component) the packets received, lost, reordered and duplicated (``SenderSeq``). ``lost`` is the
    total over the senders."""

    __slots__ = ("bytes", "frames", "bad_frames", "garbage_bytes", "lost", "senders", "truncated", "bad_stamps")

    def __init__(self) -> None:
        self.bytes = self.frames = self.bad_frames = self.garbage_bytes = self.lost = 0
        self.bad_stamps = 0  # tlog record times not plausible (``plausible_record_times``): not used, counted
        self.truncated = False  # a file that ends inside a frame (that frame is one of the bad ones)
        self.senders: dict[tuple[int, int], SenderSeq] = {}

    def sequence(self, msg) -> None:
        """Count lost packets from the per-(system, component) sequence numbers (and, across a silence
        longer than a sequence cycle, from the sender's own clock in the message: ``SenderSeq.see_timed``)."""
        key = (msg.get_srcSystem(), msg.get_srcComponent())
        sender = self.senders.get(key)
        if sender is None:
            sender = self.senders[key] = SenderSeq()
        t_us = message_time_us(msg)
        self.lost += sender.see(msg.get_seq()) if t_us is None else sender.see_timed(msg.get_seq(), t_us)

    def lost_fraction(self) -> float:
        """Lost / (received + lost) over all senders (0 before anything came)."""
        got = sum(s.received - s.duplicates for s in self.senders.values())
        return self.lost / (got + self.lost) if got + self.lost > 0 else 0.0

    def loss_summary(self) -> str:
        """``12 lost (0.10 %; 1/154: 12)``: packets lost in total, and by each sender that lost any."""
        per = ", ".join(f"{sys}/{comp}: {s.lost}" for (sys, comp), s in sorted(self.senders.items()) if s.lost)
        extra = []
        if per:
            extra.append(per)
        dups = sum(s.duplicates for s in self.senders.values())
        restarts = sum(s.restarts for s in self.senders.values())
        if dups:
            extra.append(f"{dups} duplicated")
        if restarts:
            extra.append(f"{restarts} sender restarts")
        tail = f"; {'; '.join(extra)}" if extra else ""
        return f"{self.lost} lost ({100 * self.lost_fraction():.2f} %{tail})"


def message_time_us(msg) -> int | None:
    """The sender's own clock in a message (``time_usec``, else ``time_boot_ms``), us; None if it has none, or one no
    clock can have (beyond ``samples.MAX_TIME_US``: the sample is dropped and counted there)."""
    t = getattr(msg, "time_usec", None)
    if t is None:
        ms = getattr(msg, "time_boot_ms", None)
        return None if ms is None else int(ms) * 1000
    return int(t) if 0 <= t <= MAX_TIME_US else None


class Decoder:
    """Byte stream -> MAVLink messages. Frames are found by their start byte and length (``frame_length``) and
    decoded by pymavlink (CRC, signing); a candidate whose CRC fails is a corrupted frame (one bad frame, its bytes
    skipped) unless a frame starts within its span (``_inner``): then it was a start byte in garbage, and only the
    bytes before that frame are garbage (pymavlink's own parser skips the whole span, and the frames in it). Every
    byte is a frame's, a bad frame's or garbage (counted). ``fast``: whole frames (``decode_frame``) of the sensor
    messages go through ``balloon_core.fastmav`` first (light message objects with the same fields, for the
    firmware's replay), every other one through pymavlink."""

    def __init__(self, stats: LinkStats, fast: bool = False) -> None:
        self.mav = mavlink.MAVLink(None)
        self.mav.robust_parsing = True
        self.stats = stats
        self.fast = fastmav.decode if fast else None
        self._buf = bytearray()  # bytes not yet a frame, a bad frame or garbage
        self._base = 0  # the stream offset of the buffer's first byte
        self._corrupt: set[int] = set()  # stream offsets of candidates already found not to decode (small reads)
        self._chained = True  # the scan is right after a frame (or at the stream's start)
        self._wait = 0  # where the scan stopped for more bytes: the buffer length it needs
        self._need = 0  # the same as a stream offset: a read that ends before it changes nothing (small reads)
        self._looked: dict[tuple[int, bool], int] = {}  # (a span's start, strict): where its look inside got to

    def feed(self, data: bytes, datagram: bool = False) -> list:
        """The messages in ``data``; a ``datagram`` (a link's ``datagrams``) is whole: what is left of it after its
        frames is garbage (``end_datagram``), not the start of the next one's."""
        self.stats.bytes += len(data)
        self._buf += data
        out: list = []
        if self._base + len(self._buf) >= self._need:
            self._scan(out, final=False)
        if datagram:
            self._scan(out, final=True)
            self.end_datagram()
        return out

    def _decode(self, buf: bytearray, k: int, ln: int, final: bool, chained: bool = False):
        """The message of the frame buf[k:k+ln]; None if it does not decode; False if that is not known yet. A message
        whose id the dialect does not know has no CRC pymavlink can check: it is a frame only in a chain of frames
        (``chained``: right after a known one, or at the stream's start), where another frame (or the stream's end)
        follows it and no frame that decodes starts inside it; a start byte in garbage reads as such an id most of
        the time, and would swallow the frames after it."""
        if self._base + k in self._corrupt:
            return None
        try:
            m = self.mav.decode(bytearray(buf[k : k + ln]))
        except Exception:  # pymavlink raises MAVError and struct/index errors on corrupt frames
            self._corrupt.add(self._base + k)
            return None
        if m.get_type().startswith("UNKNOWN"):
            end = k + ln
            if not chained or (end < len(buf) and not _followed(buf, end)):
                return None
            if end == len(buf) and not final:
                self._wait = end + 1
                return False
            inner = self._inner(buf, k + 1, end, final, strict=True)
            if inner:
                return None if inner > 0 else False
        return m

    def _inner(self, buf: bytearray, lo: int, hi: int, final: bool, strict: bool) -> int:
        """The first start in buf[lo:hi] of a frame that decodes (``strict``), or also of one that another frame's
        start byte follows (a frame corrupted on the way, which the scan then counts); 0 if none; -1 if that is not
        known until more bytes come."""
        key = (self._base + lo, strict)  # what was looked at inside this span before stays as it was found
        k = max(lo, self._looked.get(key, 0) - self._base)
        while (k := next_magic(buf, k)) < hi:
            ln = frame_length(buf, k)
            whole = ln > 0 and k + ln <= len(buf)
            m = self._decode(buf, k, ln, final) if whole else False
            if m is False:
                if not final:
                    if not whole:
                        self._wait = k + (ln or 3)
                    self._looked[key] = self._base + k
                    return -1
            elif m is not None:
                return k
            elif not strict:
                if k + ln == len(buf) and not final:
                    self._wait = k + ln + 1
                    self._looked[key] = self._base + k
                    return -1
                if _followed(buf, k + ln):
                    return k
            k += 1
        return 0

    def _scan(self, out: list, final: bool) -> None:
        """Frames from the buffer's start; ``final``: no more bytes will come (a datagram's or a file's end), so a
        candidate cut off is looked into for frames that decode (what is left then stays for ``end_datagram`` or
        ``finish``). The counts do not depend on how the bytes were cut into reads: what is not known yet waits."""
        buf, st, i = self._buf, self.stats, 0
        self._wait = 0
        while i < len(buf):
            k = next_magic(buf, i)
            st.garbage_bytes += k - i
            if k > i:
                self._chained = False
            i = k
            if i >= len(buf):
                break
            ln = frame_length(buf, i)
            whole = ln > 0 and i + ln <= len(buf)
            m = self._decode(buf, i, ln, final, self._chained) if whole else None
            if m is False:
                break  # wait for the bytes after it
            if m is not None:
                st.frames += 1
                st.sequence(m)
                out.append(m)
                i += ln
                self._chained = not m.get_type().startswith("UNKNOWN")
                continue
            if not (whole or final):
                self._wait = i + (ln or 3)
                break  # wait for the rest
            self._chained = False
            # a frame that decodes within its span says it was a start byte in garbage; failing that, one that a
            # frame follows says so where it is not followed by one itself (else it is a frame corrupted on the way)
            hi = i + ln if whole else len(buf)
            k = self._inner(buf, i + 1, hi, final, strict=True)
            if k == 0 and whole and i + ln == len(buf) and not final:
                self._wait = i + ln + 1
                break  # whether a frame's start byte follows it is not known yet
            if k == 0 and not (whole and _followed(buf, i + ln)):
                k = self._inner(buf, i + 1, hi, final, strict=False)
            if k < 0:
                break
            if k:  # a start byte in garbage: the frame after it is real
                st.garbage_bytes += k - i
                i = k
            elif whole:  # a corrupted frame
                st.bad_frames += 1
                i += ln
            else:  # cut off, nothing inside: left for the caller
                break
        self._need = self._base + self._wait if self._wait > i else 0
        self._consume(i)

    def _consume(self, n: int) -> None:
        del self._buf[:n]
        self._base += n
        if self._corrupt:
            self._corrupt = {o for o in self._corrupt if o >= self._base}
        if self._looked:
            self._looked = {key: v for key, v in self._looked.items() if key[0] >= self._base}

    def end_datagram(self) -> None:
        """End of one UDP datagram: a datagram holds whole frames, so the bytes left (a frame cut short, garbage)
        are counted as garbage and dropped, never joined to the next datagram's (from this or another sender),
        whose frames they would swallow."""
        self.stats.garbage_bytes += len(self._buf)
        self._consume(len(self._buf))
        self._chained = True  # the next datagram starts with a frame

    def finish(self) -> list:
        """End of a file: the frames still in its last bytes; what is left that starts a frame is a frame cut off
        (a bad frame), anything else garbage."""
        out: list = []
        self._scan(out, final=True)
        left = bytes(self._buf)
        if left and left[0] in MAGICS:
            self.stats.bad_frames += 1
            self.stats.truncated = True
        elif left:
            self.stats.garbage_bytes += len(left)
        self._consume(len(left))
        return out

    def decode_frame(self, frame: bytes):
        """One complete frame (from a tlog record); None and counted if it is corrupt."""
        self.stats.bytes += len(frame)
        if self.fast is not None:
            m = self.fast(frame)
            if m is not None:
                self.stats.frames += 1
                self.stats.sequence(m)
                return m
        try:
            m = self.mav.decode(bytearray(frame))
        except Exception:  # pymavlink raises MAVError and struct/index errors on corrupt frames
            self.stats.bad_frames += 1
            return None
        self.stats.frames += 1
        self.stats.sequence(m)
        return m


def _followed(buf: bytes, end: int) -> bool:
    """Does a frame's start byte follow at ``end`` (where a frame that ends there would be followed by the next)?"""
    return end < len(buf) and buf[end] in MAGICS


def frame_length(buf: bytes, i: int) -> int:
    """Length of the MAVLink frame starting at buf[i] (0 if it is not a frame start)."""
    if i + 3 > len(buf):
        return 0
    if buf[i] == MAGIC_V2:
        return 12 + buf[i + 1] + (13 if buf[i + 2] & 0x01 else 0)
    if buf[i] == MAGIC_V1:
        return 8 + buf[i + 1]
    return 0


def frame_msgid(frame: bytes) -> int | None:
    """The message id of a whole frame, from its header (None if it does not start with a MAVLink magic)."""
    if len(frame) >= 10 and frame[0] == MAGIC_V2:
        return frame[7] | frame[8] << 8 | frame[9] << 16
    if len(frame) >= 6 and frame[0] == MAGIC_V1:
        return frame[5]
    return None


def tlog_messages(path: str, stats: LinkStats, chunk: int = 1 << 20, fast: bool = False) -> Iterator:
    """Messages of a telemetry log: [8-byte big-endian us timestamp][frame] records, read a chunk at a
    time (memory does not grow with the file). A corrupt record is skipped by resynchronising on the
    next plausible record start; a file that ends inside a frame counts it as a bad frame
    (``stats.truncated``). Each message's ``_timestamp`` is its record's time, s (as pymavlink's tlog
    reader sets it). ``fast``: the sensor messages as ``fastmav`` messages (``Decoder``), without it."""
    dec = Decoder(stats, fast)
    with open(path, "rb") as fh:
        buf, i, eof = b"", 0, False
        while True:
            n = len(buf)
            if not eof and n - i < TLOG_HEADER + MAX_FRAME:
                more = fh.read(chunk)
                buf, i, eof = buf[i:] + more, 0, not more
                continue
            if i + TLOG_HEADER >= n:
                if n > i:  # the file ends inside a record's header
                    stats.bad_frames += 1
                    stats.truncated = True
                break
            j = i + TLOG_HEADER
            ln = frame_length(buf, j)
            if ln and j + ln > n and eof:  # the file ends inside this frame
                stats.bad_frames += 1
                stats.truncated = True
                break
            if ln == 0:
                # resync: the next byte that could start a record
                k = next_magic(buf, j + 1)
                stats.garbage_bytes += k - j
                i = k - TLOG_HEADER
                if k >= n and eof:
                    break
                continue
            end = j + ln
            orphan = end + TLOG_HEADER < n and not frame_length(buf, end + TLOG_HEADER)
            if orphan and fastmav.decode(buf[j:end]) is None:
                # no record follows this "frame": a magic byte in garbage whose length runs over the next good
                # record's start, if a frame starts within its reach that a record does follow
                k = _chained_magic(buf, j + 1, end + TLOG_HEADER)
                if k:
                    stats.garbage_bytes += k - j
                    i = k - TLOG_HEADER
                    continue
            m = dec.decode_frame(buf[j:end])
            if m is not None and not fast:  # the record's time as pymavlink's tlog reader gives it: s since the epoch
                m._timestamp = int.from_bytes(buf[i:j], "big") * 1e-6
            i = end
            if m is not None:
                yield m


T = TypeVar("T")


def plausible_record_times(items: Iterable[tuple[T, float | None]],
                           stats: LinkStats) -> Iterator[tuple[T, float | None]]:  # fmt: skip
    """(item, record time s) of a tlog's records in their order, with a time that is not plausible against its
    neighbours replaced by None and counted (``stats.bad_stamps``): a record's 8-byte time has no CRC, and one
    damaged byte puts it 36 000 years ahead (or behind) while its frame is whole. A time further than
    ``RECORD_JUMP_S`` from the last plausible one (or the first time of all) is held until the records after it
    decide (``RECORD_CONFIRM``, ``RECORD_LOOKAHEAD``); the items keep their order. A time of None passes as it is.
    Damaged times before the first plausible one (a file's first records) take that one's time, counted all the same
    (a record with no time would be stamped with the reading's clock, or put at the recording's end); None if the
    file has no plausible time at all."""
    last: float | None = None
    held: deque[tuple[T, float | None]] = deque()
    leading: list[T] = []  # damaged before any plausible time: waiting for the first one

    def decide(final: bool) -> Iterator[tuple[T, float | None]]:
        nonlocal last
        while held:
            item, t = held[0]
            if t is None or (last is not None and abs(t - last) <= RECORD_JUMP_S):
                held.popleft()
                if t is None and leading:  # behind the waiting ones, in its order
                    leading.append(item)
                    continue
                last = last if t is None else t
                yield item, t
                continue
            confirm, refuted, followers = 0, False, 0
            for _, tf in itertools.islice(held, 1, None):
                if tf is None:
                    continue
                followers += 1
                if last is not None and abs(tf - last) <= RECORD_JUMP_S:
                    refuted = True  # the clock runs on as it was: this one record's time is damaged
                    break
                if abs(tf - t) <= RECORD_JUMP_S:
                    confirm += 1
                    if confirm >= RECORD_CONFIRM:
                        break
            if not (refuted or confirm >= RECORD_CONFIRM or final or len(held) > RECORD_LOOKAHEAD):
                return  # not known yet: more records decide
            held.popleft()
            if refuted or (confirm == 0 and (followers or last is not None)):
                stats.bad_stamps += 1
                if last is None:
                    leading.append(item)
                    continue
                yield item, None
            else:  # confirmed (or the first time of a file with no other to judge it by)
                last = t
                yield from flush(t)
                yield item, t

    def flush(t: float | None) -> Iterator[tuple[T, float | None]]:
        """The damaged records before the first plausible time, with ``t`` (the first, or None at the file's end)."""
        for item in leading:
            yield item, t
        leading.clear()

    for pair in items:
        held.append(pair)
        yield from decide(False)
    yield from decide(True)
    yield from flush(None)


def _chained_magic(buf: bytes, k: int, stop: int) -> int:
    """The first frame start in buf[k:stop] that a record follows (or the buffer ends after), 0 if none."""
    while (k := next_magic(buf, k)) < stop:
        ln = frame_length(buf, k)
        after = k + ln + TLOG_HEADER
        if ln and (after >= len(buf) or frame_length(buf, after)):
            return k
        k += 1
    return 0


def next_magic(buf: bytes, k: int) -> int:
    """The index of the next byte at or after ``k`` that could start a frame (len(buf) if none)."""
    a, b = buf.find(MAGIC_V2, k), buf.find(MAGIC_V1, k)
    found = [x for x in (a, b) if x >= 0]
    return min(found) if found else len(buf)


def raw_messages(fh: BinaryIO, stats: LinkStats, chunk: int = 65536) -> Iterator:
    """Messages of a raw byte capture; a capture that ends inside a frame counts it as a bad frame."""
    dec = Decoder(stats)
    while data := fh.read(chunk):
        yield from dec.feed(data)
    yield from dec.finish()


def capture_messages(path: str, stats: LinkStats, fast: bool = False) -> Iterator:
    """The one way to open a capture by its name: a ``.tlog`` is a telemetry log, anything else raw
    MAVLink bytes as they came off a serial port. The file is closed when the iteration ends or stops.
    ``fast``: a tlog's sensor messages as ``fastmav`` messages (``Decoder``)."""
    if path.endswith(".tlog"):
        yield from tlog_messages(path, stats, fast=fast)
        return
    with open(path, "rb") as fh:
        yield from raw_messages(fh, stats)


class UdpLink:
    """``udpin:HOST:PORT`` (bind and listen; replies go to the last sender) or ``udpout:HOST:PORT``
    (send there; packets coming back are read too)."""

    datagrams = True  # each recv is one datagram, whole frames (Decoder.feed)

    def __init__(self, spec: str) -> None:
        kind, host, port = spec.split(":", 2)
        # no SO_REUSEADDR: a port another program holds (pymavlink, MAVProxy and QGroundControl set it)
        # then fails to bind instead of silently sharing (stealing) its traffic
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.peer: tuple[str, int] | None = None
        if kind == "udpin":
            try:
                self.sock.bind((host, int(port)))
            except OSError as exc:
                self.sock.close()
                if exc.errno == errno.EADDRINUSE:
                    raise ValueError(f"{spec}: UDP port {port} is already in use by another program") from None
                raise
        elif kind == "udpout":
            self.peer = (socket.gethostbyname(host), int(port))  # resolve once; an unknown host fails here
            self.sock.bind(("127.0.0.1" if host.startswith("127.") else "0.0.0.0", 0))
        else:
            raise ValueError(f"not a UDP endpoint: {spec}")
        self.sock.setblocking(False)
        self.fixed_peer = kind == "udpout"

    def recv(self, timeout_s: float) -> bytes:
        self.sock.settimeout(timeout_s)
        try:
            data, addr = self.sock.recvfrom(65536)
        except (TimeoutError, BlockingIOError):
            return b""
        except OSError:  # e.g. ICMP port unreachable reported on a connected-style socket
            return b""
        if not self.fixed_peer:
            self.peer = addr
        return data

    def send(self, data: bytes) -> None:
        if self.peer is not None:
            try:
                self.sock.sendto(data, self.peer)
            except OSError:
                pass  # nobody listening yet: UDP drops it, as a radio would

    def close(self) -> None:
        self.sock.close()


DEFAULT_BAUD = 57600


def serial_port(spec: str) -> tuple[str, int]:
    """(port, baud rate) of a serial endpoint: a device with its baud rate (``/dev/ttyUSB0:57600``, ``COM3:57600``)
    or without (``/dev/pts/3``: ``DEFAULT_BAUD``); a pyserial URL (``socket://HOST:PORT``, ``rfc2217://HOST:PORT``,
    ``loop://``) goes to pyserial whole: its ``:PORT`` is no baud rate."""
    if "://" in spec:
        return spec, DEFAULT_BAUD
    path, _, baud = spec.rpartition(":")
    if not path or not baud.isdigit():
        return spec, DEFAULT_BAUD
    return path, int(baud)


class SerialLink:
    """A serial port (``/dev/ttyUSB0:57600``, ``/dev/pts/3`` or a pyserial URL: ``serial_port``)."""

    datagrams = False  # one byte stream: a frame may span reads

    def __init__(self, spec: str) -> None:
        import serial

        path, baud = serial_port(spec)
        self.port = serial.serial_for_url(path, baudrate=baud, timeout=0, write_timeout=0.5)

    def recv(self, timeout_s: float) -> bytes:
        self.port.timeout = timeout_s
        return self.port.read(4096)

    def send(self, data: bytes) -> None:
        try:
            self.port.write(data)
        except Exception:  # nobody draining the other end: drop it, as a radio would  # noqa: BLE001
            pass

    def close(self) -> None:
        self.port.close()


def open_link(spec: str):
    """A UDP endpoint or a serial port; a clear ValueError for anything else (a missing file, say)."""
    if spec.startswith(("udpin:", "udpout:")):
        try:
            return UdpLink(spec)
        except ValueError:
            raise
        except OSError as exc:
            raise ValueError(f"cannot open {spec}: {exc}") from exc
    port = serial_port(spec)[0]
    if not (port.startswith("/dev/") or "://" in port):
        raise ValueError(f"{spec}: no such file, and not a UDP endpoint or serial port")
    try:
        return SerialLink(spec)
    except Exception as exc:  # serial.SerialException and OSError  # noqa: BLE001
        raise ValueError(f"cannot open serial port {spec}: {exc}") from exc


TLOG_EPOCH_US = 1_767_225_600_000_000  # 2026-01-01T00:00Z: records of simulated time are stamped from here


class TlogWriter:
    """Telemetry log records: each frame preceded by its 8-byte big-endian microsecond timestamp."""

    def __init__(self, fh: BinaryIO) -> None:
        self.fh = fh

    def record(self, stamp_us: int, frame: bytes) -> None:
        """A frame with its record time, us since the epoch (another tlog's, when a recording is logged again)."""
        self.fh.write(struct.pack(">Q", stamp_us) + frame)

    def write(self, time_usec: int, frame: bytes) -> None:
        """A frame at a simulated time (since boot), stamped TLOG_EPOCH_US + time_usec."""
        self.record(TLOG_EPOCH_US + time_usec, frame)


class TlogSink(TlogWriter):
    """A tlog file as a sink: ``send`` stamps wall-clock time, ``send_at`` simulated time."""

    def __init__(self, path: str) -> None:
        super().__init__(open(path, "wb"))

    def send(self, data: bytes) -> None:
        self.record(int(time.time() * 1e6), data)

    def send_at(self, data: bytes, t_us: int) -> None:
        self.write(t_us, data)

    def close(self) -> None:
        self.fh.close()


def open_sink(spec: str):
    """``*.tlog`` file, UDP endpoint or serial port."""
    if spec.endswith(".tlog"):
        return TlogSink(spec)
    return open_link(spec)
