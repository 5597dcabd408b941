"""``balloon-gs report``: score a WIND_COV log against the simulator's truth and draw the paper's
Fig. 6 (wind estimate vs truth over time, and their spectra); without a truth (a real flight), summarise and draw the
estimate alone."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from balloon_core.score import Score, direction_from_deg, lowpass, psd, score, wind_unknown
from ground_station.wind import as_arrays, read_records

TRUTH_NEEDED = ("time_s", "wind_n", "wind_e")


def _header(fh) -> list[str]:
    """A CSV's column names from its first line (a byte-order mark and spaces about the names are not part of them:
    open the file as ``utf-8-sig``)."""
    return [c.strip() for c in fh.readline().split(",")]


def read_truth(path: str) -> dict[str, np.ndarray]:
    """A balloon-sim truth CSV, checked: a header with the columns scoring needs and at least 2 rows."""
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        header = _header(fh)
        has_rows = bool(fh.readline().strip()) and bool(fh.readline().strip())
    if header == [""]:
        raise ValueError(f"{path}: the truth CSV is empty")
    missing = [c for c in TRUTH_NEEDED if c not in header]
    if missing:
        raise ValueError(f"{path}: not a balloon-sim truth CSV (no column {', '.join(missing)})")
    if not has_rows:
        raise ValueError(f"{path}: the truth CSV holds fewer than 2 rows")
    try:
        truth = read_truth_csv(path, TRUTH_NEEDED)
    except ValueError:
        truth = {}
    if not (truth and all(np.all(np.isfinite(truth[c])) for c in TRUTH_NEEDED)):
        raise ValueError(f"{path}: the truth CSV holds values that are not numbers")
    back = np.flatnonzero(np.diff(truth["time_s"]) < 0)
    if len(back):  # the scores interpolate the truth in time: rows out of order would give a wrong score, silently
        k = int(back[0])
        raise ValueError(
            f"{path}: the truth CSV's time_s goes back (data row {k + 2}: {truth['time_s'][k + 1]:g} s "
            f"after {truth['time_s'][k]:g} s); a balloon-sim truth is in time order"
        )
    return truth


def read_truth_csv(path: str, columns: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """The simulator's truth CSV (``balloon-sim --truth``): a header row, one row per IMU sample; ``columns`` (None:
    all of them) read alone, so that a day's truth (64 MB an hour, 18 columns) takes only what is asked of it."""
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        header = _header(fh)
    names = header if columns is None else list(columns)
    cols = [header.index(c) for c in names]
    data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=cols, ndmin=2)
    return {name: np.ascontiguousarray(data[:, j]) for j, name in enumerate(names)}


CLOCK_BACK_S = 1.0  # a sender's time since boot going back further than this restarted (wire.CLOCK_BACK_US)
BOOT_CONFIRM = 3  # ... when the samples after it run on from there, below where the old boot had got
BOOT_MIN = 10  # a boot with fewer samples than this is not the one scored: the longest is (a report needs 10)


def boot_starts(t_s: np.ndarray) -> list[int]:
    """Where each boot of a sender's clock starts in a log in the file's order: index 0, and each sample whose time
    since boot is more than ``CLOCK_BACK_S`` behind the newest of its boot so far while all ``BOOT_CONFIRM`` after it
    run on from it, still behind that newest (the firmware booted again, or two flights' logs end to end), and no
    later sample jumps forward again to where the old clock had got. Late packets (a few at the log's end, or a
    burst after which the clock runs on as it was) and a log in reverse order (it never runs on) are no boot."""
    starts, a = [0], 0
    while len(t_s) - a >= 1 + BOOT_CONFIRM:
        seg = t_s[a:]
        top = np.maximum.accumulate(seg)[:-1]  # the newest before each sample from the second on
        found = None
        for j in (np.flatnonzero(seg[1:] < top - CLOCK_BACK_S) + 1).tolist():
            old = top[j - 1] - CLOCK_BACK_S  # where the old boot's clock had got
            after = seg[j + 1 : j + 1 + BOOT_CONFIRM]
            if len(after) < BOOT_CONFIRM or not np.all((after >= seg[j]) & (after < old)):
                continue
            rest = seg[j:]
            if np.any((np.diff(rest) > CLOCK_BACK_S) & (rest[1:] >= old)):
                continue  # the clock jumps forward again to the old one's: a burst of late packets
            found = j
            break
        if found is None:
            break
        a += found
        starts.append(a)
    return starts


def chosen_boot(starts: list[int], n: int) -> int:
    """Which boot of a log of ``n`` samples (``boot_starts``) a report reads: the last, unless it holds fewer than
    ``BOOT_MIN`` samples (a reboot just before the log ended): then the longest (the latest of equals)."""
    lengths = [b - a for a, b in zip(starts, starts[1:] + [n], strict=True)]
    if lengths[-1] >= BOOT_MIN:
        return len(starts) - 1
    return max(range(len(lengths)), key=lambda i: (lengths[i], i))


def _boots_note(path: str, t_s: np.ndarray, starts: list[int], used: int, clock: str, one: str, many: str) -> str:
    """The one line that says a log of several boots was cut to one (``used``, ``chosen_boot``): where the clock went
    back, what is used and what is left out (``one``, ``many``: what a sample is called)."""
    k, n = starts[-1], len(t_s)
    back = (f"{path} holds {len(starts)} boots ({clock} goes back from {float(np.max(t_s[starts[-2]:k])):.1f} s to "
            f"{float(t_s[k]):.1f} s at {one} {k + 1})")  # fmt: skip
    if used == len(starts) - 1:
        earlier = len(starts) - 1
        return (f"{back}: only the last boot's {n - k} {many} are used; {k} {many} of {earlier} earlier "
                f"boot{'' if earlier == 1 else 's'} left out")  # fmt: skip
    a, b = starts[used], (starts + [n])[used + 1]
    return (f"{back}: the last boot holds only {n - k} {many} (fewer than {BOOT_MIN}): the longest, boot {used + 1}'s "
            f"{b - a} {many} ({one} {a + 1}-{b}) are used; {n - (b - a)} {many} of the other "
            f"{len(starts) - 1} boot{'' if len(starts) == 2 else 's'} left out")  # fmt: skip


def read_estimate(wind_path: str, sysid: int | None = None, notes: list[str] | None = None) -> dict[str, np.ndarray]:
    """One balloon's WIND_COV in time order (``as_arrays``) from a ground-station CSV, a .tlog, a raw capture or a
    reprocess .nc; ``sysid`` picks the balloon where the log holds more than one (else it is an error). A log of
    more than one boot (``boot_starts``: the time since boot starts again) gives its last boot's, and says so in
    ``notes``; a product whose time goes back otherwise, or that holds no finite wind, is an error."""
    if wind_path.endswith(".nc"):  # a balloon-gs reprocess product: its smoothed wind and accuracy
        from balloon_core.userargs import require_extra

        require_extra("postflight")
        from postflight.netcdf import read_netcdf_wind

        est = read_netcdf_wind(wind_path)
        t = est["time_s"]
        starts = boot_starts(t)
        used = chosen_boot(starts, len(t))
        first = starts[used]
        if len(starts) > 1:
            if notes is not None:
                notes.append(_boots_note(wind_path, t, starts, used, "time_since_boot", "estimate", "estimates"))
            est = {k: v[first : (starts + [len(t)])[used + 1]] for k, v in est.items()}
        back = np.flatnonzero(np.diff(est["time_s"]) < 0)
        if len(back):  # a product's time runs forward: out of order, its series would be scored against the wrong time
            i = int(back[0]) + 1
            raise ValueError(f"{wind_path}: the product's time goes back (estimate {first + i + 1}: "
                             f"{est['time_s'][i]:.1f} s after {est['time_s'][i - 1]:.1f} s); a product runs forward "
                             "in time")  # fmt: skip
        finite = np.isfinite(est["wind_n"]) & np.isfinite(est["wind_e"])
        if len(finite) and not finite.any():
            raise ValueError(f"{wind_path}: no finite wind in the product (its {len(finite)} estimates are all NaN)")
        est = {k: v[finite] for k, v in est.items()}
        if len(est["time_s"]) < 10:
            raise ValueError(f"{wind_path}: fewer than 10 estimates with a finite wind")
        return est
    records = read_records(wind_path)
    systems = sorted({r.sysid for r in records})
    counts = ", ".join(f"sys {s}: {sum(1 for r in records if r.sysid == s)}" for s in systems)
    if sysid is not None:
        if sysid not in systems:
            raise ValueError(f"{wind_path}: no WIND_COV from system {sysid} (it holds {counts or 'none'})")
        records = [r for r in records if r.sysid == sysid]
    elif len(systems) > 1:  # one truth scores one balloon: mixed by time, two systems' winds would score neither
        raise ValueError(
            f"{wind_path}: WIND_COV from {len(systems)} systems ({counts}); a report scores one "
            "balloon against its truth: pick it with --sysid"
        )
    t = np.array([r.time_usec for r in records], float) * 1e-6
    starts = boot_starts(t)
    if len(starts) > 1:  # keyed by time since boot, two boots' records would overwrite each other
        used = chosen_boot(starts, len(t))
        if notes is not None:
            notes.append(_boots_note(wind_path, t, starts, used, "time_usec", "WIND_COV", "WIND_COV"))
        records = records[starts[used] : (starts + [len(t)])[used + 1]]
    est = as_arrays(records)
    if len(est["time_s"]) < 10:
        raise ValueError(f"{wind_path}: fewer than 10 WIND_COV messages")
    return est


def report(wind_path: str, truth_path: str | None, plot_path: str | None = None, start_s: float = 120.0,
           sysid: int | None = None, notes: list[str] | None = None) -> Score | Summary:  # fmt: skip
    """The estimate scored against the simulator's truth (a ``Score``) and drawn; without a truth (a real flight)
    what the estimate says of itself (a ``Summary``), drawn the same way. ``notes`` gets a line for what of the log
    was left out (``read_estimate``)."""
    est = read_estimate(wind_path, sysid, notes)
    if truth_path is None:
        summ = summarise(est, start_s, wind_path)
        if plot_path:
            if summ.duration_s < 10.0:  # as a score needs: a spectrum of fewer seconds says nothing
                raise ValueError(f"{wind_path}: {summ.duration_s:.1f} s of known wind after --start {start_s:g} s; "
                                 "the figure needs 10 s")  # fmt: skip
            plot(est, None, summ.title(), plot_path, start_s)
        return summ
    truth = read_truth(truth_path)
    t_est = est["time_s"][np.isfinite(est["wind_n"]) & np.isfinite(est["wind_e"])]
    t_true = truth["time_s"]
    if len(t_est) >= 2 and min(t_est[-1], t_true[-1]) - max(t_est[0], t_true[0]) < 10.0:
        raise ValueError(
            f"{wind_path}: the estimates ({t_est[0]:.1f}-{t_est[-1]:.1f} s since boot) and the truth "
            f"{truth_path} ({t_true[0]:.1f}-{t_true[-1]:.1f} s) do not overlap for the 10 s a score "
            "needs: is it this flight's truth?"
        )
    s = score(est["time_s"], est["wind_n"], est["wind_e"], est["accuracy"],
              truth["time_s"], truth["wind_n"], truth["wind_e"], start_s=start_s)  # fmt: skip
    if not math.isfinite(s.mean_accuracy_mps):  # the error is scored; the stated accuracy cannot be judged
        raise ValueError(f"{wind_path}: no finite horiz_accuracy among the estimates scored from --start {start_s:g} s "
                         f"({s.accuracy_not_finite} not a finite number)")  # fmt: skip
    if plot_path:
        plot(est, truth, score_title(s), plot_path, start_s)
    return s


@dataclass(frozen=True)
class Summary:
    """What a WIND_COV log says of itself over ``duration_s`` from the start time: the mean wind vector's speed and
    the direction it comes from, the mean of the speeds, the RMS of the reported accuracy, and the share of the
    estimates that are not known (NaN, or an accuracy as large as the wind: ``score.wind_unknown``)."""

    mean_speed_mps: float
    from_deg: float
    speed_mean_mps: float
    accuracy_mps: float
    unknown_share: float
    messages: int
    duration_s: float

    def title(self) -> str:
        return (f"mean wind {self.mean_speed_mps:.2f} m/s from {self.from_deg:.0f}°, "
                f"horiz_accuracy {self.accuracy_mps:.2f} m/s (RMS), {self.duration_s:.0f} s")  # fmt: skip


def summarise(est: dict, start_s: float, path: str) -> Summary:
    t = est["time_s"]
    n, e, acc = est["wind_n"], est["wind_e"], est["accuracy"]
    sel = t >= start_s
    known = sel & ~np.asarray(wind_unknown(np.hypot(n, e), acc), bool) & np.isfinite(n) & np.isfinite(e)
    if known.sum() < 2:
        raise ValueError(f"{path}: fewer than 2 known winds from {start_s:g} s on (--start)")
    mn, me = float(np.mean(n[known])), float(np.mean(e[known]))
    return Summary(math.hypot(mn, me), float(direction_from_deg(mn, me)), float(np.mean(np.hypot(n, e)[known])),
                   float(np.sqrt(np.mean(acc[known] ** 2))), 1.0 - known.sum() / max(int(sel.sum()), 1),
                   int(sel.sum()), float(t[known][-1] - t[known][0]))  # fmt: skip


def direction_from(wind_n: np.ndarray, wind_e: np.ndarray, centre_deg: float) -> np.ndarray:
    """Meteorological direction (where the wind comes FROM, deg clockwise from north), wrapped into
    centre +- 180 deg so that a wind around north does not jump between 0 and 360 on the plot."""
    d = direction_from_deg(wind_n, wind_e)
    return (d - centre_deg + 180.0) % 360.0 - 180.0 + centre_deg


def score_title(s: Score) -> str:
    return (f"band RMSE {s.band_rmse_mps:.2f} m/s, speed error {s.speed_error_pct:+.1f} %, "
            f"direction error {s.direction_error_deg:+.1f}°, error/accuracy {s.error_ratio:.2f}")  # fmt: skip


def plot(est: dict, truth: dict | None, heading: str, path: str, start_s: float, band_hz: float = 0.05) -> None:
    """The paper's Fig. 6 and more: speed with the reported accuracy, direction, the low-passed speed
    (the band that is scored) from the launch on, and the spectra with the band edge; the truth's beside each where
    there is one (a simulated flight)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fs = 10.0
    t_end = est["time_s"][-1] if truth is None else min(est["time_s"][-1], truth["time_s"][-1])
    grid = np.arange(0.0, t_end, 1.0 / fs)
    finite = np.isfinite(est["wind_n"]) & np.isfinite(est["wind_e"])
    sp_est = np.interp(grid, est["time_s"][finite], np.hypot(est["wind_n"], est["wind_e"])[finite])
    sp_true = None if truth is None else np.interp(grid, truth["time_s"], np.hypot(truth["wind_n"], truth["wind_e"]))
    scored = grid >= start_s
    fig, ax = plt.subplots(4, 1, figsize=(9, 11.5))
    t_all = est["time_s"]
    speed = np.hypot(est["wind_n"], est["wind_e"])
    if truth is not None:
        ax[0].plot(truth["time_s"], np.hypot(truth["wind_n"], truth["wind_e"]), lw=0.6, label="truth", color="0.5")
    ax[0].plot(t_all, speed, lw=0.8, label="estimate (WIND_COV)")
    ax[0].fill_between(t_all, speed - est["accuracy"], speed + est["accuracy"], alpha=0.2,
                       label="± horiz_accuracy")  # fmt: skip
    ax[0].set_ylabel("wind speed [m/s]")
    ax[0].set_ylim(0, max(6.0, 1.3 * np.percentile(sp_est if sp_true is None else sp_true, 99)))
    ax[0].legend(loc="upper right", fontsize=8)
    ref = est if truth is None else truth
    ok = (ref["time_s"] >= start_s) & np.isfinite(ref["wind_n"]) & np.isfinite(ref["wind_e"])
    if not ok.any():
        ok = np.isfinite(ref["wind_n"]) & np.isfinite(ref["wind_e"])
    centre = float(direction_from_deg(np.mean(ref["wind_n"][ok]), np.mean(ref["wind_e"][ok])))
    if truth is not None:
        ax[1].plot(truth["time_s"], direction_from(truth["wind_n"], truth["wind_e"], centre), lw=0.6,
                   label="truth", color="0.5")  # fmt: skip
    moving = speed > 0.3  # the direction of a near-zero estimate (before the release) means nothing
    ax[1].plot(t_all[moving], direction_from(est["wind_n"], est["wind_e"], centre)[moving], ".", ms=1.0,
               label="estimate (speed > 0.3 m/s)")  # fmt: skip
    ax[1].set_ylabel("direction (from) [deg]")
    ax[1].set_ylim(centre - 60.0, centre + 60.0)
    ax[1].legend(loc="upper right", fontsize=8, markerscale=6)
    if sp_true is not None:
        ax[2].plot(grid, lowpass(sp_true, fs, band_hz), label=f"truth < {band_hz:g} Hz", color="0.3")
    ax[2].plot(grid, lowpass(sp_est, fs, band_hz), label=f"estimate < {band_hz:g} Hz")
    not_used = "not summarised" if truth is None else "not scored"
    ax[2].axvspan(0.0, start_s, color="0.9", label=f"{not_used} (before {start_s:g} s)")
    ax[2].set_ylabel("low-passed speed [m/s]")
    ax[2].legend(loc="upper right", fontsize=8)
    for a in ax[:3]:
        a.set_xlim(0.0, t_end)
        a.set_xlabel("time since boot [s]")
    f, p_est = psd(sp_est[scored], fs)
    if sp_true is not None:
        ax[3].loglog(f[1:], psd(sp_true[scored], fs)[1][1:], label="truth", color="0.4")
    ax[3].loglog(f[1:], p_est[1:], label="estimate")
    ax[3].axvline(band_hz, ls=":", color="k", lw=0.8, label=f"{band_hz:g} Hz: upper edge of the scored band")
    ax[3].set_xlabel(f"frequency [Hz] (speed from {start_s:g} s on)")
    ax[3].set_ylabel("PSD [(m/s)²/Hz]")
    ax[3].legend(loc="lower left", fontsize=8)
    fig.suptitle(heading)
    fig.tight_layout()
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def format_score(s: Score | Summary) -> str:
    if isinstance(s, Summary):
        return (
            f"no truth: the estimate alone | mean wind {s.mean_speed_mps:.2f} m/s from {s.from_deg:.1f} deg "
            f"(mean speed {s.speed_mean_mps:.2f} m/s) | horiz_accuracy {s.accuracy_mps:.2f} m/s (RMS) | "
            f"{100 * s.unknown_share:.1f} % of {s.messages} WIND_COV not known | {s.duration_s:.0f} s"
        )
    return (
        f"band RMSE (<0.05 Hz) {s.band_rmse_mps:.3f} m/s, skill {s.band_skill:.2f} | "
        f"raw RMSE {s.raw_rmse_mps:.3f} m/s | "
        f"mean speed {s.est_speed_mps:.2f} vs {s.true_speed_mps:.2f} m/s ({s.speed_error_pct:+.1f} %) | "
        f"direction error {s.direction_error_deg:+.2f} deg | horiz_accuracy {s.mean_accuracy_mps:.2f} m/s "
        f"(actual error / accuracy {s.error_ratio:.2f}{_left_out(s.accuracy_not_finite)}) | {s.duration_s:.0f} s scored"
    )


def _left_out(n: int) -> str:
    """``; 3 accuracies not finite, left out`` (of the accuracy's statistics), or nothing."""
    return f"; {n} {'accuracy' if n == 1 else 'accuracies'} not finite, left out" if n else ""
