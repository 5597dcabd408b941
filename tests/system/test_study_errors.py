"""balloon-study's user errors that must be caught before any work, fast: too many workers or cases, seeds
balloon-sim refuses, an unwritable DIR/parts, a --scheduler address where no Dask scheduler answers (nothing,
a banner, silence, a web server), no directory left behind by a refused run; SIGTERM answered as Ctrl-C."""

from __future__ import annotations

import http.server
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from study import engine
from study.cli import main, max_workers
from study.spec import MAX_CASES, Spec

ROOT = Path(__file__).resolve().parents[2]
ONE = '[study]\nduration_s = 80.0\nstart_s = 40.0\n[axes]\n"balloon.radius_m" = [1.15]\n'


@pytest.fixture
def no_work(monkeypatch):
    """Any case made, cluster started or sweep run fails the test (the checks must come first)."""

    def refuse(*a, **k):
        raise AssertionError("work started before the inputs were checked")

    monkeypatch.setattr(Spec, "cases", refuse)
    monkeypatch.setattr(engine, "dask_client", refuse)
    monkeypatch.setattr(engine, "run", refuse)


def one_line_exit_2(capsys, argv: list[str], *words: str) -> str:
    assert main(argv) == 2, argv
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, (w, err)
    return err


def test_workers_above_4_per_core_is_exit_2_naming_the_limit(tmp_path, capsys, no_work):
    spec = tmp_path / "one.toml"
    spec.write_text(ONE)
    out = tmp_path / "o"
    one_line_exit_2(capsys, [str(spec), "--out", str(out), "--workers", "100000"], "--workers", str(max_workers()))
    assert max_workers() == 4 * (os.cpu_count() or 1) and not out.exists()


@pytest.mark.parametrize(
    "text, words",
    [
        ("[study]\nseeds = 1000000000\n", f"1 .. {MAX_CASES}"),
        ('[axes]\n"balloon.radius_m" = {start = 0.9, stop = 1.5, num = 100000000}\n', f"at most {MAX_CASES}"),
        (
            '[study]\nseeds = 1000\n[axes]\n"balloon.radius_m" = {start = 0.9, stop = 1.5, num = 1000}\n',
            "1000000 cases",
        ),  # fmt: skip
        ("[study]\nseeds = [1, 5000000000]\n", "0 .. 4294967295"),  # balloon-sim --seed's range
        ("[study]\nseeds = [-1]\n", "0 .. 4294967295"),
    ],
)
def test_too_many_cases_and_seeds_balloon_sim_refuses_are_exit_2(tmp_path, capsys, no_work, text, words):
    spec = tmp_path / "s.toml"
    spec.write_text(text.replace("[study]\n", "[study]\nduration_s = 80.0\nstart_s = 40.0\n") if "[study]" in text
                    else "[study]\nduration_s = 80.0\nstart_s = 40.0\n" + text)  # fmt: skip
    out = tmp_path / "o"
    one_line_exit_2(capsys, [str(spec), "--out", str(out), "--workers", "0"], words)
    assert not out.exists()


def test_seeds_option_beyond_the_most_cases_is_exit_2(tmp_path, capsys, no_work):
    spec = tmp_path / "one.toml"
    spec.write_text(ONE)
    out = tmp_path / "o"
    one_line_exit_2(capsys, [str(spec), "--out", str(out), "--workers", "0", "--seeds", "1000000000"], "--seeds")
    two = ONE.replace("[1.15]", "[1.0, 1.15]")
    spec.write_text(two)
    one_line_exit_2(capsys, [str(spec), "--out", str(out), "--workers", "0", "--seeds", str(MAX_CASES)],
                    f"{2 * MAX_CASES} cases")  # fmt: skip
    assert not out.exists()


def test_an_avionics_offset_outside_the_sphere_is_exit_2_before_any_case(tmp_path, capsys, no_work):
    """As docs/study.md says: an error naming the point, not a failed row."""
    spec = tmp_path / "av.toml"
    spec.write_text(ONE.replace('"balloon.radius_m" = [1.15]', '"truth.avionics_offset_m" = [0.0, 1.5]'))
    out = tmp_path / "o"
    one_line_exit_2(capsys, [str(spec), "--out", str(out), "--workers", "0"], "avionics_offset_m = 1.5", "sphere")
    assert not out.exists()


def test_an_unwritable_parts_or_plots_directory_is_exit_2_before_any_case(tmp_path, capsys, no_work):
    spec = tmp_path / "one.toml"
    spec.write_text(ONE)
    for name in ("parts", "plots"):
        out = tmp_path / f"o-{name}"
        (out / name).mkdir(parents=True)
        if os.geteuid() == 0:  # root writes through a mode of 555: make it immutable instead
            if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", str(out / name)]).returncode:
                pytest.skip("running as root where chattr +i is not possible")
        else:
            (out / name).chmod(0o555)
        try:
            one_line_exit_2(capsys, [str(spec), "--out", str(out), "--workers", "0"], f"{out / name}",
                            "not writable")  # fmt: skip
            if name == "plots":  # not written with --no-plots: not refused for it (the no_work guard trips)
                with pytest.raises(AssertionError, match="work started"):
                    main([str(spec), "--out", str(out), "--workers", "0", "--no-plots"])
        finally:
            if os.geteuid() == 0:
                subprocess.run(["chattr", "-i", str(out / name)], check=True)
            else:
                (out / name).chmod(0o755)
        assert sorted(p.name for p in out.iterdir()) == [name] and not any((out / name).iterdir())


# ---------------------------------------------------------------- --scheduler where no scheduler is


class Peer:
    """A TCP server on loopback that is not Dask: sends a banner first, or says nothing at all."""

    def __init__(self, banner: bytes | None) -> None:
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.held: list[socket.socket] = []
        self.banner = banner
        threading.Thread(target=self.serve, daemon=True).start()

    def serve(self) -> None:
        while True:
            try:
                c, _ = self.sock.accept()
            except OSError:
                return
            if self.banner:
                c.sendall(self.banner)
            self.held.append(c)  # kept open and silent

    def close(self) -> None:
        self.sock.close()
        for c in self.held:
            c.close()


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args) -> None:  # its log would be the test's stderr
        pass


@pytest.fixture
def peer(request):
    kind = request.param
    if kind == "http":  # as `python3 -m http.server PORT`
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), QuietHandler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        yield f"tcp://127.0.0.1:{server.server_address[1]}"
        server.shutdown()
        server.server_close()
        return
    p = Peer(b"SSH-2.0-OpenSSH_9.6p1 Ubuntu-3ubuntu13\r\n" if kind == "banner" else None)
    yield f"tcp://127.0.0.1:{p.port}"
    p.close()


@pytest.mark.parametrize("peer", ["banner", "silent", "http"], indirect=True)
def test_no_dask_scheduler_at_the_address_is_exit_2_within_the_timeout(tmp_path, capsys, monkeypatch, no_work, peer):
    monkeypatch.setattr(engine, "SCHEDULER_TIMEOUT_S", 1.0)
    spec = tmp_path / "one.toml"
    spec.write_text(ONE)
    out = tmp_path / "o"
    t0 = time.monotonic()
    one_line_exit_2(capsys, [str(spec), "--out", str(out), "--scheduler", peer], f"no Dask scheduler at {peer}")
    assert time.monotonic() - t0 < 5.0
    assert not out.exists()


@pytest.mark.parametrize("peer", ["banner", "silent"], indirect=True)
def test_check_scheduler_ends_within_its_deadline_whatever_the_peer_does(peer):
    t0 = time.monotonic()
    with pytest.raises(engine.NoScheduler):
        engine.check_scheduler(peer, timeout_s=0.5)
    assert time.monotonic() - t0 < 3.0


def test_a_scheduler_that_cannot_be_reached_leaves_no_directory(tmp_path, capsys, monkeypatch, no_work):
    monkeypatch.setattr(engine, "SCHEDULER_TIMEOUT_S", 1.0)
    spec = tmp_path / "one.toml"
    spec.write_text(ONE)
    out = tmp_path / "o"
    one_line_exit_2(capsys, [str(spec), "--out", str(out), "--scheduler", "tcp://127.0.0.1:1"],
                    "no Dask scheduler at tcp://127.0.0.1:1")  # fmt: skip
    assert not out.exists()
    out.mkdir()  # an existing --out is kept, and nothing is made in it
    one_line_exit_2(capsys, [str(spec), "--out", str(out), "--scheduler", "tcp://127.0.0.1:1"], "no Dask scheduler")
    assert out.is_dir() and not any(out.iterdir())


@pytest.mark.dask
def test_check_scheduler_accepts_a_scheduler_and_refuses_a_worker():
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, processes=False, dashboard_address=None) as cluster:
        engine.check_scheduler(cluster.scheduler_address, timeout_s=5.0)
        worker = next(iter(cluster.scheduler_info["workers"]))
        with pytest.raises(engine.NoScheduler, match="Worker"):
            engine.check_scheduler(worker, timeout_s=5.0)


# ---------------------------------------------------------------- SIGTERM


def test_sigterm_is_answered_as_ctrl_c(tmp_path):
    """The sweep stops, the finished parts stay, one line says how to resume; exit 143 (128 + SIGTERM)."""
    spec = tmp_path / "long.toml"
    spec.write_text(ONE.replace("duration_s = 80.0", "duration_s = 3600.0"))
    out = tmp_path / "o"
    p = subprocess.Popen([sys.executable, "-m", "study", str(spec), "--out", str(out), "--workers", "0"], cwd=ROOT,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        first = p.stderr.readline()  # printed as the sweep starts
        assert "1 cases" in first, first
        time.sleep(0.5)
        p.send_signal(signal.SIGTERM)
        _, rest = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert p.returncode == 128 + signal.SIGTERM, rest
    assert "Traceback" not in rest and rest.strip().splitlines()[-1] == (
        f"balloon-study: terminated; the finished cases are kept in {out / 'parts'}: run the same command again "
        "to resume"
    )
    assert (out / "parts").is_dir()
