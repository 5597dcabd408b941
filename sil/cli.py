"""``balloon-sil``: software in the loop. Starts ``balloon-sim``, ``balloon-fw`` and ``balloon-gs`` as
three processes talking MAVLink over UDP on loopback, shows the ground station's live line, stops
them all cleanly (also on Ctrl-C or when one of them dies), then scores the run and plots it.

    sim --udpout--> fw (udpin) --udpout--> gs (udpin)
        <--WIND_COV-- (lockstep)
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time

from balloon_core import userargs
from balloon_core.atomic import Products, atomic_open


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Children:
    """The three processes; whatever happens, none outlives us."""

    def __init__(self) -> None:
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, args: list[str], **kw) -> subprocess.Popen:
        p = subprocess.Popen([sys.executable, "-m", *args], **kw)
        self.procs[name] = p
        return p

    def stop(self, name: str, grace_s: float = 5.0) -> None:
        p = self.procs.get(name)
        if p is None or p.poll() is not None:
            return
        p.send_signal(signal.SIGTERM)
        try:
            p.wait(grace_s)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()

    def stop_all(self) -> None:
        for name in reversed(list(self.procs)):
            self.stop(name)

    def dead(self) -> list[str]:
        return [n for n, p in self.procs.items() if p.poll() is not None]


PROG = "balloon-sil"
DEFAULT_START_S = 120.0  # the estimator has settled by then (release at 5 s)
MIN_SCORED_S = 20.0  # the least a score is computed over


def last_lines(text: str | None, n: int = 5) -> str:
    lines = [ln for ln in (text or "").strip().splitlines() if ln.strip()]
    return "\n".join("    " + ln for ln in lines[-n:]) or "    (nothing on stderr)"


def score_start(duration_s: float, start_s: float | None) -> float | None:
    """Where scoring starts: ``start_s`` if given, else 120 s, moved earlier for a short run so that at
    least MIN_SCORED_S are scored (never before 40 % of the run); None if the run is too short."""
    if start_s is None:
        start_s = min(DEFAULT_START_S, max(0.4 * duration_s, duration_s - MIN_SCORED_S - 1.0))
    return start_s if duration_s - start_s >= MIN_SCORED_S else None


def main(argv: list[str] | None = None) -> int:
    ap = userargs.Parser(prog=PROG, description="simulator + firmware + ground station")
    ap.add_argument("--scenario", help="named scenario (default paper-reference, with --config the real world: "
                    "field-rope with the file's sections)")  # fmt: skip
    ap.add_argument("--duration", type=userargs.duration, default=600.0, help="simulated seconds")
    ap.add_argument("--seed", type=userargs.seed, default=1)
    ap.add_argument("--speed", type=userargs.positive_speed, default=10.0,
                    help="N x real time (lockstep keeps it lossless)")
    ap.add_argument("--config", type=userargs.input_file, help="TOML design file for simulator and firmware")
    ap.add_argument("--outdir", type=userargs.output_dir, default="out", help="truth, logs and plot go here")
    ap.add_argument("--start", type=userargs.start_time,
                    help="score from this time since boot [s] (default 120, earlier for a short run)")
    args = ap.parse_args(argv)
    from sim_hil.scenarios import scenario_name

    args.scenario = scenario_name(args.scenario, args.config)
    tag = f"{args.scenario}-seed{args.seed}"
    truth = os.path.join(args.outdir, f"{tag}-truth.csv")
    gs_csv = os.path.join(args.outdir, f"{tag}-wind.csv")
    gs_tlog = os.path.join(args.outdir, f"{tag}-gs.tlog")
    plot = os.path.join(args.outdir, f"{tag}.png")
    design = os.path.join(args.outdir, f"{tag}-design.toml")
    try:  # the one rule for output options: what it writes in --outdir is none of its inputs
        if os.path.realpath(args.outdir).startswith("/proc/"):
            raise userargs.UserError(f"--outdir {args.outdir}: cannot be written (under /proc)")
        if os.path.isdir(args.outdir):  # (a directory still to be made holds no input)
            userargs.check_outputs({"--config": args.config}, {f"--outdir ({os.path.basename(p)})": p
                                                               for p in (truth, gs_csv, gs_tlog, plot, design)})
    except userargs.UserError as exc:
        return userargs.fail(PROG, exc)
    # one design file for both: the scenario with the user's file applied (the firmware must be told
    # what the scenario's balloon, tether and sensors are, and how to filter); judged before --outdir is made
    from balloon_core.config import ConfigError
    from sim_hil.scenarios import resolve

    try:
        sc = resolve(args.scenario, args.config)
    except ConfigError as exc:
        return userargs.fail(PROG, exc)
    if sc.filter.core == "c":  # the firmware's C core, built before anything starts (balloon-sil has no --core)
        from firmware_c.build import BuildError, library

        try:
            library("float" if sc.filter.float32 else "double")
        except BuildError as exc:
            return userargs.fail(PROG, f'{exc}; or run the Python core: [filter] core = "py" in the --config file')
    try:
        os.makedirs(args.outdir, exist_ok=True)
    except OSError as exc:
        return userargs.fail(PROG, f"--outdir {args.outdir}: {exc.strerror or exc}")
    p_fw, p_gs = free_port(), free_port()
    with atomic_open(design) as fh:
        fh.write(sc.to_toml())
    cfg = ["--config", design]
    kids = Children()
    stop = userargs.stop_flag()
    latest = [""]
    t_start = time.monotonic()
    tty = sys.stdout.isatty()
    # our header first: on a terminal the ground station then draws its live view below it (a line printed
    # after the view's first frame would shift it, leaving a copy of that frame and overwriting the header)
    print(f"balloon-sil: {args.scenario}, {args.duration:.0f} s at {args.speed:g}x, seed {args.seed} "
          f"(sim -> udp:{p_fw} -> fw -> udp:{p_gs} -> gs)", flush=True)  # fmt: skip
    try:
        gs_args = ["ground_station", "listen", f"udpin:127.0.0.1:{p_gs}", "--csv", gs_csv, "--tlog", gs_tlog]
        # on a terminal the ground station draws its live view there itself; otherwise we relay its lines
        gs = kids.start("gs", gs_args, stdout=None if tty else subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        if not tty:
            threading.Thread(target=_follow, args=(gs.stdout, latest), daemon=True).start()
        fw_args = ["firmware_py", "--in", f"udpin:127.0.0.1:{p_fw}", "--out", f"udpout:127.0.0.1:{p_gs}", "--quiet",
                   *cfg]  # fmt: skip
        kids.start("fw", fw_args, stderr=subprocess.PIPE, text=True)
        time.sleep(0.5)  # let both bind before the sensors start flowing
        sim = kids.start("sim", ["sim_hil", "--scenario", args.scenario, "--duration", str(args.duration),
                                 "--seed", str(args.seed), "--out", f"udpout:127.0.0.1:{p_fw}", "--truth", truth,
                                 "--speed", str(args.speed), "--lockstep", "--quiet", *cfg],
                         stderr=subprocess.PIPE, text=True)  # fmt: skip
        next_show = 0.0
        while sim.poll() is None:
            if stop():
                break
            died = [n for n in kids.dead() if n != "sim"]
            if died:
                print(f"\n{PROG}: {', '.join(died)} died; stopping all", file=sys.stderr)
                for n in died:
                    p = kids.procs[n]
                    print(f"  {n} (exit {p.returncode}), last lines on its stderr:\n"
                          f"{last_lines(p.stderr.read())}", file=sys.stderr)  # fmt: skip
                return 1
            now = time.monotonic()
            if not tty and now >= next_show and latest[0]:
                print(latest[0], flush=True)
                next_show = now + 10.0
            time.sleep(0.1)
        if stop() or sim.returncode == 130:
            kids.stop_all()
            said = [ln for ln in sim.stderr.read().splitlines() if "simulated" in ln]
            if said:
                print(said[-1], file=sys.stderr)
            print(f"{PROG}: interrupted after {time.monotonic() - t_start:.0f} s; logs so far in {args.outdir}",
                  file=sys.stderr)  # fmt: skip
            return 130
        if sim.returncode != 0:
            print(f"{PROG}: simulator failed (exit {sim.returncode}), last lines on its stderr:\n"
                  f"{last_lines(sim.stderr.read())}", file=sys.stderr)  # fmt: skip
            return 1
        time.sleep(1.0)  # the last WIND_COV reach the ground station
        kids.stop("fw")
        kids.stop("gs")
        tails = {}
        for name in ("sim", "fw"):
            err = kids.procs[name].stderr.read().strip()
            tails[name] = err
            if err:
                print(err.splitlines()[-1])
        tails["gs"] = gs.stderr.read().strip()
        print(tails["gs"])
    finally:
        kids.stop_all()
    wall = time.monotonic() - t_start
    from ground_station.report import format_score, report

    start = score_start(args.duration, args.start)
    if start is None:
        after = "" if args.start is None else f" from {args.start:g} s"
        print(f"{PROG}: a {args.duration:g} s run is too short to score{after} (needs {MIN_SCORED_S:g} s of "
              f"settled estimates); logs: {gs_csv}, {gs_tlog}   truth: {truth}")  # fmt: skip
        return 0
    try:
        with Products() as products:
            s = report(gs_csv, truth, products.path(plot), start)
            products.commit()
    except ValueError as exc:
        print(f"{PROG}: cannot score: {exc}", file=sys.stderr)
        return 1
    print(f"score: {format_score(s)}" + (f" (from {start:g} s)" if start != DEFAULT_START_S else ""))
    print(f"plot: {plot}   logs: {gs_csv}, {gs_tlog}   truth: {truth}   design: {design}   wall time {wall:.0f} s")
    print(loss_line(tails.get("sim", ""), tails.get("fw", ""), tails.get("gs", "")))
    return 0


def loss_line(sim_err: str, fw_err: str, gs_err: str) -> str:
    """The run's last word on data: what the firmware lost from the simulator, what the ground station
    lost from the firmware (both from MAVLink sequence numbers), and lockstep timeouts."""
    import re

    def grab(pattern: str, text: str) -> int | None:
        m = re.findall(pattern, text)
        return int(m[-1]) if m else None

    up = grab(r"input packets (\d+) lost", fw_err)
    gaps = grab(r"(\d+) long gaps", fw_err)
    down = grab(r"(\d+) lost, \d+ CRC errors", gs_err)
    timeouts = grab(r"lockstep: (\d+) timeouts", sim_err) or 0
    if up is None or down is None:
        return "balloon-sil: losses unknown (a program did not report them)"
    parts = f"sim -> fw {up} packets lost, {gaps or 0} long gaps; fw -> gs {down} lost; {timeouts} lockstep timeouts"
    if up or down or gaps or timeouts:
        return f"balloon-sil: DATA LOST: {parts}"
    return f"balloon-sil: nothing lost ({parts})"


def _follow(stream, latest: list[str]) -> None:
    for line in stream:
        latest[0] = line.strip()


if __name__ == "__main__":
    sys.exit(main())
