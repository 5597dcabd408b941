"""``balloon-sil``: software in the loop. Starts ``balloon-sim``, ``balloon-fw`` and ``balloon-gs`` as
three processes talking MAVLink over UDP on loopback, shows the ground station's live line, stops
them all cleanly (also on Ctrl-C or when one of them dies), then scores the run and plots it.

    sim --udpout--> fw (udpin) --udpout--> gs (udpin)
        <--WIND_COV-- (lockstep)
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import threading
import time


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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="balloon-sil", description="simulator + firmware + ground station")
    ap.add_argument("--scenario", default="paper-reference")
    ap.add_argument("--duration", type=float, default=600.0, help="simulated seconds")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--speed", type=float, default=10.0, help="N x real time (lockstep keeps it lossless)")
    ap.add_argument("--config", help="TOML design file for simulator and firmware")
    ap.add_argument("--outdir", default="out", help="truth, logs and plot go here")
    args = ap.parse_args(argv)
    os.makedirs(args.outdir, exist_ok=True)
    tag = f"{args.scenario}-seed{args.seed}"
    truth = os.path.join(args.outdir, f"{tag}-truth.csv")
    gs_csv = os.path.join(args.outdir, f"{tag}-wind.csv")
    gs_tlog = os.path.join(args.outdir, f"{tag}-gs.tlog")
    plot = os.path.join(args.outdir, f"{tag}.png")
    p_fw, p_gs = free_port(), free_port()
    # one design file for both: the scenario with the user's file applied (the firmware must be told
    # what the scenario's balloon, tether and sensors are, and how to filter)
    from firmware_py.config import ConfigError
    from sim_hil.scenarios import resolve

    try:
        sc = resolve(args.scenario, args.config)
    except ConfigError as exc:
        print(f"balloon-sil: {exc}", file=sys.stderr)
        return 2
    design = os.path.join(args.outdir, f"{tag}-design.toml")
    with open(design, "w") as fh:
        fh.write(sc.to_toml())
    cfg = ["--config", design]
    kids = Children()
    stopping: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stopping.append(1))
    latest = [""]
    t_start = time.monotonic()
    tty = sys.stdout.isatty()
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
        print(f"balloon-sil: {args.scenario}, {args.duration:.0f} s at {args.speed:g}x, seed {args.seed} "
              f"(sim -> udp:{p_fw} -> fw -> udp:{p_gs} -> gs)")  # fmt: skip
        next_show = 0.0
        while sim.poll() is None:
            if stopping:
                print("\nballoon-sil: interrupted, stopping all", file=sys.stderr)
                return 130
            died = [n for n in kids.dead() if n != "sim"]
            if died:
                print(f"\nballoon-sil: {', '.join(died)} died; stopping all", file=sys.stderr)
                return 1
            now = time.monotonic()
            if not tty and now >= next_show and latest[0]:
                print(latest[0], flush=True)
                next_show = now + 10.0
            time.sleep(0.1)
        if sim.returncode != 0:
            print(f"balloon-sil: simulator failed:\n{sim.stderr.read()}", file=sys.stderr)
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

    try:
        s = report(gs_csv, truth, plot)
    except ValueError as exc:
        print(f"balloon-sil: cannot score: {exc}", file=sys.stderr)
        return 1
    print(f"score: {format_score(s)}")
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
