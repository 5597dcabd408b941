"""The system on the wire (loopback and ptys only): SIL run, clean stops, lossy links, sensor
silence, restarts, garbage, serial replay through pseudo-terminals, pymavlink's own tools."""

import math
import os
import pty
import re
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from balloon_core.wire import Decoder, LinkStats
from ground_station.report import report
from tests.helpers.relay import LossyRelay

pytestmark = [pytest.mark.network]

PY = sys.executable


def procs_with(text: str) -> list[int]:
    """PIDs of live processes whose command line contains ``text``."""
    out = []
    for pid in os.listdir("/proc"):
        if pid.isdigit() and int(pid) != os.getpid():
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as fh:
                    cmd = fh.read().replace(b"\0", b" ").decode(errors="replace")
                with open(f"/proc/{pid}/stat") as fh:
                    zombie = fh.read().split(") ")[1].startswith("Z")
            except OSError:
                continue
            if text in cmd and not zombie:
                out.append(int(pid))
    return out


def udp_bound(port: int, timeout_s: float = 30.0) -> bool:
    """Wait until a process has bound UDP ``port`` here (``/proc/net/udp``), whatever its start-up time."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for table in ("/proc/net/udp", "/proc/net/udp6"):
            try:
                with open(table) as fh:
                    if any(row.split()[1].endswith(f":{port:04X}") for row in fh.readlines()[1:]):
                        return True
            except OSError:
                continue
        time.sleep(0.05)
    return False


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    d = tmp_path_factory.mktemp("link")
    tlog = d / "sensors.tlog"
    subprocess.run([PY, "-m", "sim_hil", "--duration", "60", "--seed", "2", "--out", str(tlog)], check=True)
    return tlog


def test_sil_run_scores_and_leaves_no_process(tmp_path):
    r = subprocess.run([PY, "-m", "sil.cli", "--duration", "200", "--speed", "25", "--seed", "3",
                        "--outdir", str(tmp_path)], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    m = re.search(r"band RMSE \(<0.05 Hz\) ([\d.]+) m/s, skill (-?[\d.]+)", r.stdout)
    assert m and float(m.group(1)) < 0.2 and float(m.group(2)) > 0.15  # 80 s scored: the pipeline, not the accuracy
    assert "0 lost" in r.stdout  # lockstep on loopback: lossless at 25x
    assert r.stdout.strip().splitlines()[-1].startswith("balloon-sil: nothing lost (sim -> fw 0 packets lost")
    assert (tmp_path / "paper-reference-seed3.png").stat().st_size > 10_000
    assert not procs_with(str(tmp_path))
    ports = re.search(r"udp:(\d+) -> fw -> udp:(\d+)", r.stdout).groups()
    assert not any(procs_with(f"127.0.0.1:{p}") for p in ports)


def _start_sil(tmp_path, duration="600"):
    p = subprocess.Popen([PY, "-m", "sil.cli", "--duration", duration, "--speed", "2", "--outdir",
                          str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    banner = p.stdout.readline()
    ports = re.search(r"udp:(\d+) -> fw -> udp:(\d+)", banner).groups()
    deadline = time.monotonic() + 20
    while len(procs_with(f"127.0.0.1:{ports[0]}")) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)  # fw (udpin) and sim (udpout) up
    time.sleep(2.0)
    return p, ports


def test_sil_ctrl_c_stops_all_three(tmp_path):
    p, ports = _start_sil(tmp_path)
    p.send_signal(signal.SIGINT)
    p.wait(20)
    assert p.returncode == 130
    time.sleep(0.5)
    assert not any(procs_with(f"127.0.0.1:{port}") for port in ports)


def test_sil_stops_all_when_one_dies(tmp_path):
    p, ports = _start_sil(tmp_path)
    fw = [pid for pid in procs_with(f"udpin:127.0.0.1:{ports[0]}") if pid != p.pid]
    assert fw
    os.kill(fw[0], signal.SIGKILL)
    p.wait(20)
    assert p.returncode == 1 and "died" in p.stderr.read()
    time.sleep(0.5)
    assert not any(procs_with(f"127.0.0.1:{port}") for port in ports)


def test_lossy_reordering_link_still_converges_and_losses_are_counted(tmp_path):
    p_fw, p_gs = free_port(), free_port()
    truth, csv = tmp_path / "truth.csv", tmp_path / "wind.csv"
    with LossyRelay(p_fw, loss=0.1, reorder=0.05, seed=1) as up, LossyRelay(p_gs, loss=0.1, seed=2) as down:
        gs_cmd = [PY, "-m", "ground_station", "listen", f"udpin:127.0.0.1:{p_gs}", "--csv", str(csv)]
        gs = subprocess.Popen(gs_cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        fw_cmd = [PY, "-m", "firmware_py", "--in", f"udpin:127.0.0.1:{p_fw}", "--out", f"udpout:127.0.0.1:{down.port}"]
        fw = subprocess.Popen(fw_cmd, stderr=subprocess.PIPE, text=True)
        time.sleep(0.5)
        # 480 s: six minutes scored (from 120 s), where two minutes of a band below 0.05 Hz made the skill depend on
        # which packets the link happened to lose (0.45-0.55 between runs of the same flight)
        subprocess.run([PY, "-m", "sim_hil", "--duration", "480", "--seed", "4", "--truth", str(truth),
                        "--out", f"udpout:127.0.0.1:{up.port}", "--speed", "20", "--lockstep"],
                       check=True, timeout=120, capture_output=True)  # fmt: skip
        time.sleep(1.0)
        for proc in (fw, gs):
            proc.send_signal(signal.SIGINT)
            proc.wait(10)
    fw_summary, gs_summary = fw.stderr.read(), gs.stderr.read()
    assert up.dropped > 1000 and down.dropped > 100
    lost = int(re.search(r"(\d+) lost", gs_summary).group(1))
    assert lost > 0.5 * down.dropped  # the ground station counts the losses from sequence numbers
    gaps = int(re.search(r"(\d+) gaps", fw_summary).group(1))
    reordered = int(re.search(r"(\d+) reordered", fw_summary).group(1))
    assert gaps > 100 and reordered > 10
    s = report(str(csv), str(truth))
    # 10 % of the sensor packets lost, 5 % reordered: still better than the constant true mean by far
    assert s.band_skill >= 0.5 and abs(s.speed_error_pct) < 5, s


def wind_cov_listener(port: int, records: list, stop: threading.Event):
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    sock.settimeout(0.1)
    dec = Decoder(LinkStats())
    while not stop.is_set():
        try:
            data = sock.recv(65536)
        except (TimeoutError, OSError):
            continue
        for m in dec.feed(data):
            if m.get_type() == "WIND_COV":
                records.append((time.monotonic(), m.time_usec, m.horiz_accuracy))
    sock.close()


def test_firmware_live_survives_silence_garbage_and_restart(capture):
    p_fw, p_out = free_port(), free_port()
    records, stop = [], threading.Event()
    listener = threading.Thread(target=wind_cov_listener, args=(p_out, records, stop), daemon=True)
    listener.start()
    fw = subprocess.Popen([PY, "-m", "firmware_py", "--in", f"udpin:127.0.0.1:{p_fw}", "--out",
                           f"udpout:127.0.0.1:{p_out}"], stderr=subprocess.PIPE, text=True)  # fmt: skip
    time.sleep(0.5)
    replay = [PY, "-m", "sim_hil.replay", str(capture), "--out", f"udpout:127.0.0.1:{p_fw}", "--speed", "15"]
    subprocess.run(replay, check=True, timeout=60, capture_output=True)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # line noise and a broken frame
        s.sendto(bytes(range(256)) * 4, ("127.0.0.1", p_fw))
        s.sendto(b"\xfd\x10\x00\x00\x01\x01\x01\x69\x00\x00" + b"\x00" * 12, ("127.0.0.1", p_fw))
    t_silence = time.monotonic()
    time.sleep(3.0)  # sensors silent: WIND_COV keeps coming, accuracy grows
    during = [r for r in records if r[0] > t_silence + 0.6]
    assert len(during) >= 15
    assert during[-1][2] > during[0][2] and all(r[1] == during[0][1] for r in during)
    subprocess.run(replay, check=True, timeout=60, capture_output=True)  # the simulator restarted
    time.sleep(0.5)
    fw.send_signal(signal.SIGTERM)
    fw.wait(10)
    stop.set()
    summary = fw.stderr.read()
    assert fw.returncode == 0
    assert "12000 IMU samples" in summary or int(re.search(r"(\d+) IMU samples", summary).group(1)) > 11000
    assert int(re.search(r"(\d+) bad frames", summary).group(1)) >= 1
    # the replay's time going back is a reboot, and nothing else would count as one
    assert int(re.search(r"(\d+) reboot", summary).group(1)) == 1
    assert records[-1][1] > 50_000_000 and math.isfinite(records[-1][2])


def test_firmware_parses_each_datagram_on_its_own():
    """A datagram holds whole frames: one that ends inside a frame it started (a v2 start claiming 16 bytes of payload
    it does not carry) is garbage, and the next datagram's frame is taken whole, not eaten as its missing bytes."""
    port = free_port()
    fw = subprocess.Popen([PY, "-m", "firmware_py", "--in", f"udpin:127.0.0.1:{port}"], stderr=subprocess.PIPE,
                          text=True)  # fmt: skip
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    broken = b"\xfd\x10\x00\x00\x01\x01\x01\x69\x00\x00" + b"\x00" * 12
    try:
        assert udp_bound(port), "balloon-fw did not bind its input port"
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for k in range(300):
                s.sendto(broken, ("127.0.0.1", port))
                imu = mav.highres_imu_encode(10_000 * (k + 1), 0, 0, -9.8, 0, 0, 0, 0.2, 0, 0.4, 1000.0, 0, 0, 20.0,
                                             0x1FFF, 0)  # fmt: skip
                s.sendto(imu.pack(mav), ("127.0.0.1", port))
                time.sleep(0.002)
        time.sleep(0.3)
    finally:
        fw.send_signal(signal.SIGTERM)
        fw.wait(10)
    summary = fw.stderr.read()
    counts = {k: int(re.search(rf"(\d+) {k}", summary).group(1)) for k in ("IMU samples", "rejected", "garbage bytes")}
    # every IMU frame decoded (taken, or judged and rejected: these are no flight's), every broken one garbage
    assert counts == {"IMU samples": counts["IMU samples"], "rejected": 300 - counts["IMU samples"],
                      "garbage bytes": 300 * len(broken)}, summary  # fmt: skip


def test_mavlogdump_reads_the_firmware_log(capture, tmp_path):
    out = tmp_path / "fw.tlog"
    subprocess.run([PY, "-m", "firmware_py", "--in", str(capture), "--out", str(out)], check=True, capture_output=True)
    dump = os.path.join(os.path.dirname(PY), "mavlogdump.py")
    r = subprocess.run([PY, dump, "--types", "WIND_COV,HEARTBEAT", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert sum("WIND_COV" in ln for ln in lines) == 600
    assert any(f"HEARTBEAT {{type : {mavlink.MAV_TYPE_FREE_BALLOON}," in ln for ln in lines)


class Cable(threading.Thread):
    """A null-modem cable between two pty masters (and drains masters nobody reads)."""

    def __init__(self, pairs, drains=()):
        super().__init__(daemon=True)
        self.pairs, self.drains = pairs, drains
        self.stop = threading.Event()

    def run(self):
        import select

        fds = [a for a, _ in self.pairs] + list(self.drains)
        route = dict(self.pairs)
        while not self.stop.is_set():
            ready, _, _ = select.select(fds, [], [], 0.1)
            for fd in ready:
                try:
                    data = os.read(fd, 65536)
                except OSError:
                    continue
                if fd in route:
                    os.write(route[fd], data)


def test_serial_replay_through_ptys(capture, tmp_path):
    a_m, a_s = pty.openpty()  # replay -> a
    b_m, b_s = pty.openpty()  # b -> firmware
    c_m, c_s = pty.openpty()  # firmware -> c
    d_m, d_s = pty.openpty()  # d -> ground station
    names = [os.ttyname(fd) for fd in (a_s, b_s, c_s, d_s)]
    cable = Cable([(a_m, b_m), (c_m, d_m)], drains=[b_m])
    cable.start()
    csv = tmp_path / "wind.csv"
    gs = subprocess.Popen([PY, "-m", "ground_station", "listen", f"{names[3]}:115200", "--csv", str(csv)],
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # fmt: skip
    fw = subprocess.Popen([PY, "-m", "firmware_py", "--in", f"{names[1]}:115200", "--out", f"{names[2]}:115200"],
                          stderr=subprocess.PIPE, text=True)  # fmt: skip
    time.sleep(1.0)
    r = subprocess.run([PY, "-m", "sim_hil.replay", str(capture), "--out", f"{names[0]}:115200", "--speed", "10"],
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 0, r.stderr
    time.sleep(1.0)
    for proc in (fw, gs):
        proc.send_signal(signal.SIGTERM)
        proc.wait(10)
    cable.stop.set()
    fw_summary, gs_summary = fw.stderr.read(), gs.stderr.read()
    n_imu = int(re.search(r"(\d+) IMU samples", fw_summary).group(1))
    assert n_imu > 5900, fw_summary
    n_wind = int(re.search(r"(\d+) WIND_COV", gs_summary).group(1))
    assert n_wind > 500, gs_summary
    last = csv.read_text().strip().splitlines()[-1].split(",")
    assert 1.5 < float(last[11]) < 4.5  # speed_mps
    assert mavlink.MAVLINK_MSG_ID_WIND_COV == 231


def test_a_pyserial_url_is_given_to_pyserial_whole():
    """``socket://HOST:PORT`` (pyserial's serial port over TCP): the URL's ``:PORT`` is no baud rate. ``listen``
    reads WIND_COV through it; a device's ``:BAUD`` stays a baud rate."""
    from balloon_core.wire import pack, serial_port

    assert serial_port("socket://127.0.0.1:28032") == ("socket://127.0.0.1:28032", 57600)
    assert serial_port("rfc2217://10.0.0.5:2217") == ("rfc2217://10.0.0.5:2217", 57600)
    assert serial_port("loop://") == ("loop://", 57600)
    assert serial_port("/dev/ttyUSB0:921600") == ("/dev/ttyUSB0", 921600)
    assert serial_port("/dev/pts/3") == ("/dev/pts/3", 57600)
    mav = mavlink.MAVLink(None, srcSystem=3, srcComponent=1)
    frames = [pack(mav, mav.wind_cov_encode(1_000_000 + 100_000 * i, 2.0, -1.0, math.nan, 0.1, 0.0, 50.0, 0.3, 0.0))
              for i in range(500)]  # fmt: skip
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen()
        srv.settimeout(30)

        def serve() -> None:
            conn, _ = srv.accept()
            with conn:
                for f in frames:  # paced, until the listener hangs up (pyserial drops what came before its open)
                    try:
                        conn.sendall(f)
                    except OSError:
                        return
                    time.sleep(0.02)

        t = threading.Thread(target=serve, daemon=True)
        t.start()
        url = f"socket://127.0.0.1:{srv.getsockname()[1]}"
        r = subprocess.run([PY, "-m", "ground_station", "listen", url, "--duration", "3"], capture_output=True,
                           text=True, timeout=60)  # fmt: skip
        t.join(10)
    assert r.returncode == 0, r.stderr
    got = re.search(r"(\d+) WIND_COV from 1 system, (\d+) frames, 0 lost, 0 CRC errors, 0 garbage bytes", r.stderr)
    assert got and int(got.group(1)) >= 20, r.stderr
