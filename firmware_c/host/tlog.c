/* The host's tlog scanner (not flashed: firmware_c/build.py adds host/ to the host library only): a file
 * replay's records framed, checked and, for the common frames, taken all the way into the sample block
 * here instead of one Python message each, and the usual block through the C core with its WIND_COV
 * (firmware_py/replay.py holds the state and does everything else; see there). A tlog record is an 8-byte
 * big-endian time stamp and one MAVLink 1 or 2 frame.
 *
 * The framing is balloon_core/wire.py tlog_messages' rule for rule (resynchronisation on garbage, the
 * orphan check, a file that ends inside a record), and a frame counts as a sensor frame exactly when
 * balloon_core/fastmav.py decode would decode it (message, length, CRC with CRC_EXTRA). */
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "bw_core.h"

int bw_on_batch(bw_estimator_t *est, int n, const int64_t *t_us, const int32_t *kind, const double *v,
                int64_t stop_us, int32_t told_flags, int64_t text_us, int32_t *stepped, int64_t *steps,
                int32_t *modes, int32_t *flags);

#define HDR 8
#define MAX_FRAME 280

/* the state array (int64), shared with firmware_py/replay.py (its S_* names) */
enum {
    S_I, S_N, S_EOF, S_LANE, S_J, S_END, S_BYTES, S_FRAMES, S_GARBAGE, S_BAD, S_TRUNC,
    S_IMU_MID, S_IMU_SYS, S_IMU_COMP, S_IMU_ID, S_HAVE_IMU, S_EMBEDDED, S_OTHERS, S_IGNORED, S_BESIDE,
    S_HAVE_BARO, S_BARO_MID, S_BARO_SYS, S_BARO_COMP, S_GROUND, S_SAMPLES, S_MISSING, S_PREV, S_BLOCK_T,
    S_DT, S_NEXT_WIND, S_NEXT_HB, S_LEN, S_BATCH, S_ROWS, S_RECENT, S_NSEND,
    /* the outputs (Firmware.run_block, _count, _judge, emit_due, wind_cov) */
    S_EMIT, S_TOLD, S_NEXT_TEXT, S_SENT, S_SEQ, S_SYSID, S_COMPID, S_PERIOD, S_MSG_ID, S_MSG_EXTRA, S_GROUND_MODE,
    S_NSRC, S_LAST_STEP, S_FLIGHT, S_MISFIT, S_NOUT = S_MISFIT + 8, S_DONE, S_SINCE, S_SENDERS = 80
};
/* a sender's fields (SenderSeq), 16 a sender from S_SENDERS */
enum { Q_SYS, Q_COMP, Q_RECEIVED, Q_NEWEST, Q_BEHIND, Q_T0, Q_I0, Q_TMID, Q_IMID, Q_TLAST, Q_ILAST, Q_USABLE };
#define Q_SIZE 16

/* what stopped a scan */
#define R_MORE 0  /* the buffer needs more of the file (or the file is done: S_I at its end) */
#define R_END 1   /* the end of the file */
#define R_FRAME 2 /* the frame S_J .. S_END is for Python (decode and handle it; then S_I = S_END) */
#define R_DRAIN 3 /* a frame was taken and its sample may make an output due: drain the block */
#define R_BATCHED 4 /* as R_DRAIN, the block's first S_DONE samples already through the C core */
#define R_OUT 5   /* the output buffer is full: send what is in it */
#define OUT_CAP 64
#define OUT_SLOT 64

static const struct { uint32_t id; uint8_t extra; uint8_t size; } TABLE[] = {
    {105, 93, 63}, {107, 108, 65}, {26, 170, 24}, {116, 76, 24}, {129, 46, 24},
    {29, 115, 16}, {137, 195, 16}, {143, 131, 16}, {9005, 117, 34},
};

static uint16_t crc_acc(uint16_t crc, uint8_t b)
{
    uint8_t t = (uint8_t)(b ^ (uint8_t)(crc & 0xff));
    t = (uint8_t)(t ^ (uint8_t)(t << 4));
    return (uint16_t)((crc >> 8) ^ ((uint16_t)t << 8) ^ ((uint16_t)t << 3) ^ ((uint16_t)t >> 4));
}

/* fastmav.decode's verdict: the frame's message id (>= 0) when it would decode it, else -1; the payload
 * (zero padded to the message's size, extensions cut) in pay */
static int64_t fast_frame(const uint8_t *f, int64_t n, uint8_t *pay, int *seq, int *sys, int *comp)
{
    int64_t hl, tail, mlen, end, k;
    uint32_t id;
    unsigned t;
    uint16_t crc = 0xFFFF;
    if (n < 8) return -1;
    if (f[0] == 0xFD) {
        if (n < 12) return -1;
        hl = 10;
        id = (uint32_t)f[7] | (uint32_t)f[8] << 8 | (uint32_t)f[9] << 16;
        tail = 2 + ((f[2] & 1) ? 13 : 0);
        *seq = f[4]; *sys = f[5]; *comp = f[6];
    } else if (f[0] == 0xFE) {
        hl = 6;
        id = f[5];
        tail = 2;
        *seq = f[2]; *sys = f[3]; *comp = f[4];
    } else {
        return -1;
    }
    for (t = 0; t < sizeof TABLE / sizeof TABLE[0]; t++)
        if (TABLE[t].id == id) break;
    if (t == sizeof TABLE / sizeof TABLE[0]) return -1;
    mlen = f[1];
    if (mlen != n - hl - tail) return -1;
    end = n - tail;
    for (k = 1; k < end; k++) crc = crc_acc(crc, f[k]);
    crc = crc_acc(crc, TABLE[t].extra);
    if (crc != (uint16_t)(f[end] | f[end + 1] << 8)) return -1;
    memset(pay, 0, 255);
    memcpy(pay, f + hl, (size_t)(mlen < TABLE[t].size ? mlen : TABLE[t].size));
    return id;
}

static int64_t frame_length(const uint8_t *b, int64_t n, int64_t i)
{
    if (i + 3 > n) return 0;
    if (b[i] == 0xFD) return 12 + b[i + 1] + ((b[i + 2] & 1) ? 13 : 0);
    if (b[i] == 0xFE) return 8 + b[i + 1];
    return 0;
}

static int64_t next_magic(const uint8_t *b, int64_t n, int64_t k)
{
    for (; k < n; k++)
        if (b[k] == 0xFD || b[k] == 0xFE) return k;
    return n;
}

static int64_t chained_magic(const uint8_t *b, int64_t n, int64_t k, int64_t stop)
{
    while ((k = next_magic(b, n, k)) < stop) {
        int64_t ln = frame_length(b, n, k), after = k + ln + HDR;
        if (ln && (after >= n || frame_length(b, n, after))) return k;
        k++;
    }
    return 0;
}

static uint64_t u64(const uint8_t *p) { uint64_t v; memcpy(&v, p, 8); return v; }
static uint32_t u32(const uint8_t *p) { uint32_t v; memcpy(&v, p, 4); return v; }
static uint16_t u16(const uint8_t *p) { return (uint16_t)(p[0] | p[1] << 8); }
static double f32(const uint8_t *p) { float v; memcpy(&v, p, 4); return (double)v; }
static int16_t i16(const uint8_t *p) { int16_t v; memcpy(&v, p, 2); return v; }

static void row(int64_t *S, int64_t *rt, int32_t *rk, double *rv, int64_t t, int kind, const double *v)
{
    int64_t r = S[S_ROWS]++;
    rt[r] = t;
    rk[r] = kind;
    memcpy(rv + 9 * r, v, 9 * sizeof(double));
    S[S_LEN]++;
    S[S_SAMPLES]++;
}

/* MavlinkSampler._stuck: the accelerometer's, the gyro's and the magnetometer's readings (D[1..9]) and since when
 * each has repeated (S[S_SINCE + i], -1: it changed), updated with this HIGHRES_IMU's; whether any has repeated for
 * STUCK_US (samples.py) */
static int stuck(int64_t *S, double *D, int64_t t, const uint8_t *p, uint16_t bits)
{
    int i, j, out = 0;
    for (i = 0; i < 3; i++) {
        double v[3];
        int same = 1;
        for (j = 0; j < 3; j++) {
            v[j] = i == 2 && (bits & 0x1C0) != 0x1C0 ? (double)NAN : f32(p + 8 + 12 * i + 4 * j);
            if (i == 2 && !isfinite(v[j])) v[j] = (double)NAN;
            same = same && v[j] == D[1 + 3 * i + j];
        }
        if (same) {
            if (S[S_SINCE + i] < 0)
                S[S_SINCE + i] = t;
            else if (t - S[S_SINCE + i] >= 1000000)
                out = 1;
        } else {
            S[S_SINCE + i] = -1;
            for (j = 0; j < 3; j++) D[1 + 3 * i + j] = v[j];
        }
    }
    return out;
}

/* One sensor frame through what firmware_py does with it (LinkStats.sequence, MavlinkSampler.convert,
 * Firmware.push and _step with a decided rate and no averaging), when it is the common case; else 0 and
 * nothing changed (Python takes the frame). 1: taken; 3: taken, drain the block. */
static int lane(int64_t *S, double *D, int64_t id, const uint8_t *p, int seq, int sys, int comp, int64_t *rt,
                int32_t *rk, double *rv, int64_t *recent)
{
    int64_t t, *q = 0, k;
    int embedded_beside = 0, pressure = 0, drain = 0;
    uint16_t bits = 0;
    if (id == 105) {
        uint64_t tu = u64(p);
        if (tu > (UINT64_C(1) << 53)) return 0; /* beyond samples.MAX_TIME_US: Python counts it and drops it */
        t = (int64_t)tu;
        if (!S[S_HAVE_IMU] || S[S_IMU_MID] != 105 || S[S_IMU_SYS] != sys || S[S_IMU_COMP] != comp ||
            S[S_IMU_ID] != p[62])
            return 0;
        bits = u16(p + 60);
        if (!bits) bits = 0xFFFF;
        pressure = (bits & 0x200) != 0;
        if (pressure && S[S_LEN] + 1 >= S[S_BATCH]) return 0;
        if (t <= S[S_PREV]) return 0; /* a late, repeated or restarted IMU time: Python's bookkeeping */
        if ((bits & 0x1C0) == 0x1C0 &&
            !(isfinite(f32(p + 32)) && isfinite(f32(p + 36)) && isfinite(f32(p + 40))))
            return 0; /* a magnetometer reading that is not a number: MavlinkSampler counts it */
        if ((bits & 0x1200) == 0x1200 && !isfinite(f32(p + 56)))
            return 0; /* ... and a thermometer's */
        if (S[S_PREV] >= 0 && t - S[S_PREV] > 1000000) return 0; /* a new clock or a glitch: app.ClockGuard's */
    } else if (id == 29) {
        t = (int64_t)u32(p) * 1000;
        if (!S[S_HAVE_IMU] || sys == S[S_GROUND] || sys != S[S_IMU_SYS]) return 0;
        if (!(S[S_HAVE_BARO] && S[S_BARO_SYS] == S[S_IMU_SYS])) return 0; /* Python chooses the barometer */
        if (S[S_EMBEDDED]) {
            embedded_beside = 1;
        } else if (S[S_BARO_MID] != 29 || S[S_BARO_COMP] != comp || S[S_BARO_SYS] != sys) {
            return 0;
        }
    } else {
        return 0;
    }
    /* the sender's sequence (SenderSeq.see_timed): only the usual next packet, no holes */
    for (k = 0; k < S[S_NSEND]; k++) {
        int64_t *c = S + S_SENDERS + Q_SIZE * k;
        if (c[Q_SYS] == sys && c[Q_COMP] == comp) q = c;
    }
    if (!q || !q[Q_USABLE] || q[Q_NEWEST] < 0 || q[Q_BEHIND] != 0) return 0;
    if (((seq - q[Q_NEWEST]) % 256 + 256) % 256 != 1) return 0;
    if (q[Q_TLAST] < 0 || t < q[Q_TLAST] - 1000000 || t - q[Q_TLAST] > 86400000000LL) return 0;
    {
        int64_t span = q[Q_TLAST] - q[Q_T0];
        if (span >= 1000000 && q[Q_ILAST] > q[Q_I0]) {
            int64_t a = t - q[Q_TLAST], b = q[Q_ILAST] - q[Q_I0];
            double expected;
            if ((a < 0 ? -a : a) > (INT64_C(1) << 53) / b) return 0; /* a * b exact in a double: else Python */
            expected = (double)q[Q_ILAST] + (double)(a * b) / (double)span;
            if (expected - (double)q[Q_NEWEST] > 64.0) return 0;
        }
    }
    if (id == 105 && (bits & 0x3F) == 0x3F && stuck(S, D, t, p, bits))
        return 0; /* a sensor stuck (MavlinkSampler._stuck, which left the state as it was): Python's */
    /* taken: from here on, what Python would do */
    q[Q_RECEIVED]++;
    q[Q_NEWEST]++;
    q[Q_BEHIND] = 0;
    if (t >= q[Q_TLAST]) {
        if (t - q[Q_TMID] > 10000000) {
            q[Q_T0] = q[Q_TMID]; q[Q_I0] = q[Q_IMID];
            q[Q_TMID] = q[Q_TLAST]; q[Q_IMID] = q[Q_ILAST];
        }
        q[Q_TLAST] = t; q[Q_ILAST] = q[Q_NEWEST];
    }
    if (id == 29) {
        double v[9] = {0};
        if (embedded_beside) {
            S[S_BESIDE]++;
            return 1;
        }
        v[0] = f32(p + 4);
        v[1] = (double)i16(p + 12) / 100.0;
        row(S, rt, rk, rv, t, 1, v);
        return S[S_LEN] >= S[S_BATCH] ? 3 : 1;
    }
    S[S_OTHERS] = 0;
    if (pressure) {
        double v[9] = {0}, temp;
        S[S_EMBEDDED] = 1;
        if (bits & 0x1000) D[0] = f32(p + 56);
        temp = D[0];
        v[0] = f32(p + 44);
        v[1] = isfinite(temp) ? temp : 15.0;
        row(S, rt, rk, rv, t, 1, v);
    }
    {
        double v[9];
        int j;
        if ((bits & 0x3F) != 0x3F) {
            for (j = 0; j < 9; j++) v[j] = NAN;
        } else {
            for (j = 0; j < 6; j++) v[j] = f32(p + 8 + 4 * j);
            if ((bits & 0x1C0) == 0x1C0) {
                for (j = 6; j < 9; j++) v[j] = f32(p + 8 + 4 * j);
            } else {
                v[6] = v[7] = v[8] = NAN;
            }
        }
        /* Firmware._track_imu_time, t > the previous IMU time */
        if (S[S_PREV] >= 0) {
            int64_t m = (t - S[S_PREV] + S[S_DT] / 2) / S[S_DT] - 1;
            if (m > 0) S[S_MISSING] += m;
        }
        recent[S[S_RECENT]++] = t;
        S[S_PREV] = t;
        row(S, rt, rk, rv, t, 0, v);
        drain = t >= S[S_NEXT_WIND] || t >= S[S_NEXT_HB] || t < S[S_BLOCK_T] || S[S_LEN] >= S[S_BATCH];
        S[S_BLOCK_T] = t;
    }
    return drain ? 3 : 1;
}

/* Firmware._count of samples 0 .. n-1 (those that stepped) */
static void count_steps(int64_t *S, int n, const int32_t *stepped, const int64_t *steps, const int32_t *modes,
                        const int32_t *flags)
{
    int k, i;
    for (k = 0; k < n; k++) {
        int64_t d;
        if (!(stepped[k] & 1)) continue;
        d = steps[k] - S[S_LAST_STEP];
        S[S_LAST_STEP] = steps[k];
        if (d > 0 && modes[k] != S[S_GROUND_MODE]) {
            S[S_FLIGHT] += d;
            for (i = 0; i < S[S_NSRC]; i++)
                if (flags[k] >> i & 1) S[S_MISFIT + i] += d;
        }
    }
}

/* The block's rows through the C core (Firmware.run_block) and, in the usual case (the whole block in one
 * piece ending on a step, no STATUSTEXT, no HEARTBEAT, no WIND due with it), what Python does after it
 * (the step counts, WIND_COV packed as pymavlink packs it) here: 1. Else 0, the first S_DONE rows done. */
static int run_rows(int64_t *S, bw_estimator_t *est, int64_t *rt, int32_t *rk, double *rv, int32_t *stepped,
                    int64_t *steps, int32_t *modes, int32_t *flags, uint8_t *out, int64_t *out_meta)
{
    int n = (int)S[S_ROWS], done, last;
    int64_t t, stop = S[S_NEXT_WIND] < S[S_NEXT_HB] ? S[S_NEXT_WIND] : S[S_NEXT_HB];
    bw_wind_cov_t f;
    done = bw_on_batch(est, n, rt, rk, rv, stop, (int32_t)S[S_TOLD], S[S_NEXT_TEXT], stepped, steps, modes, flags);
    S[S_DONE] = done;
    last = done - 1;
    if (done != n || stepped[last] != 1) return 0;
    t = rt[last];
    if (flags[last] != S[S_TOLD] && t >= S[S_NEXT_TEXT]) return 0; /* a STATUSTEXT */
    if (t >= S[S_NEXT_HB]) return 0;
    if (t >= S[S_NEXT_WIND]) {
        uint8_t *o = out + OUT_SLOT * S[S_NOUT], pay[40];
        int plen = 40, k;
        uint16_t crc = 0xFFFF;
        if (S[S_SENT] % 10 == 0 && est->initialised) return 0; /* WIND first */
        bw_wind_cov(est, &f);
        if (f.time_usec < 0) return 0;
        memcpy(pay, &f.time_usec, 8);
        memcpy(pay + 8, &f.wind_x, 4);
        memcpy(pay + 12, &f.wind_y, 4);
        memcpy(pay + 16, &f.wind_z, 4);
        memcpy(pay + 20, &f.var_horiz, 4);
        memcpy(pay + 24, &f.var_vert, 4);
        memcpy(pay + 28, &f.wind_alt, 4);
        memcpy(pay + 32, &f.horiz_accuracy, 4);
        memcpy(pay + 36, &f.vert_accuracy, 4);
        while (plen > 1 && pay[plen - 1] == 0) plen--; /* MAVLink 2 cuts trailing zeros */
        o[0] = 0xFD;
        o[1] = (uint8_t)plen;
        o[2] = o[3] = 0;
        o[4] = (uint8_t)S[S_SEQ];
        o[5] = (uint8_t)S[S_SYSID];
        o[6] = (uint8_t)S[S_COMPID];
        o[7] = (uint8_t)(S[S_MSG_ID] & 0xFF);
        o[8] = (uint8_t)(S[S_MSG_ID] >> 8 & 0xFF);
        o[9] = (uint8_t)(S[S_MSG_ID] >> 16 & 0xFF);
        memcpy(o + 10, pay, (size_t)plen);
        for (k = 1; k < 10 + plen; k++) crc = crc_acc(crc, o[k]);
        crc = crc_acc(crc, (uint8_t)S[S_MSG_EXTRA]);
        o[10 + plen] = (uint8_t)(crc & 0xFF);
        o[11 + plen] = (uint8_t)(crc >> 8);
        out_meta[2 * S[S_NOUT]] = t;
        out_meta[2 * S[S_NOUT] + 1] = 12 + plen;
        S[S_NOUT]++;
        S[S_SEQ] = (S[S_SEQ] + 1) % 256;
        S[S_SENT]++;
        S[S_NEXT_WIND] = t - t % S[S_PERIOD] + S[S_PERIOD];
    }
    count_steps(S, n, stepped, steps, modes, flags);
    S[S_ROWS] = S[S_LEN] = 0;
    return 1;
}

/* Scan buf[S_I .. S_N) (S_EOF: the file ends there) as tlog_messages does, until Python must act (R_*).
 * With S_LANE the common sensor frames are taken here (``lane``); every other frame is returned. */
int bw_tlog_scan(const uint8_t *buf, int64_t *S, double *D, int64_t *rt, int32_t *rk, double *rv,
                 int64_t *recent, bw_estimator_t *est, int32_t *stepped, int64_t *steps, int32_t *modes,
                 int32_t *flags, uint8_t *out, int64_t *out_meta)
{
    int64_t n = S[S_N], i = S[S_I];
    int eof = (int)S[S_EOF];
    uint8_t pay[256];
    S[S_BYTES] = S[S_FRAMES] = S[S_GARBAGE] = S[S_BAD] = S[S_TRUNC] = 0; /* what this call did */
    S[S_IGNORED] = S[S_BESIDE] = S[S_SAMPLES] = S[S_RECENT] = 0; /* S_ROWS: the rows not yet taken */
    S[S_FLIGHT] = S[S_NOUT] = S[S_DONE] = 0;
    memset(S + S_MISFIT, 0, 8 * sizeof S[0]);
    for (;;) {
        int64_t j, ln, end, id = -1;
        int seq = 0, sys = 0, comp = 0, r;
        if (!eof && n - i < HDR + MAX_FRAME) { S[S_I] = i; return R_MORE; }
        if (i + HDR >= n) {
            if (n > i) { S[S_BAD]++; S[S_TRUNC] = 1; }
            S[S_I] = n;
            return R_END;
        }
        j = i + HDR;
        ln = frame_length(buf, n, j);
        if (ln && j + ln > n && eof) { S[S_BAD]++; S[S_TRUNC] = 1; S[S_I] = n; return R_END; }
        if (ln == 0) {
            int64_t k = next_magic(buf, n, j + 1);
            S[S_GARBAGE] += k - j;
            i = k - HDR;
            if (k >= n && eof) { S[S_I] = n; return R_END; }
            continue;
        }
        end = j + ln;
        if (end <= n) id = fast_frame(buf + j, ln, pay, &seq, &sys, &comp);
        if (end + HDR < n && !frame_length(buf, n, end + HDR) && id < 0) {
            int64_t k = chained_magic(buf, n, j + 1, end + HDR);
            if (k) {
                S[S_GARBAGE] += k - j;
                i = k - HDR;
                continue;
            }
        }
        if (id < 0 || !S[S_LANE] || !(r = lane(S, D, id, pay, seq, sys, comp, rt, rk, rv, recent))) {
            S[S_J] = j;
            S[S_END] = end;
            S[S_I] = i;
            return R_FRAME;
        }
        S[S_BYTES] += ln;
        S[S_FRAMES]++;
        i = end;
        if (r == 3) {
            S[S_I] = i;
            if (!S[S_EMIT] || S[S_LEN] != S[S_ROWS]) return R_DRAIN; /* Python's own samples wait too */
            if (!run_rows(S, est, rt, rk, rv, stepped, steps, modes, flags, out, out_meta)) return R_BATCHED;
            if (S[S_NOUT] == OUT_CAP) return R_OUT;
        }
    }
}
