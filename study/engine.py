"""Running the cases: on Dask distributed (an embedded LocalCluster, or any cluster by its scheduler
address), or serially in this process. Every finished case is stored at once as one small JSON part
under ``DIR/parts/<key>.json``, so an interrupted sweep resumes and a repeated one costs nothing.

Only metrics dicts travel back to the client; at most ``window`` cases are in flight at a time, so
the client holds O(workers) payloads whatever the sweep's size."""

from __future__ import annotations

import contextlib
import importlib.util
import json
import logging
import os
import signal
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from study.case import run_case
from study.spec import Case

CaseFn = Callable[[dict[str, Any]], dict[str, Any]]


class Store:
    """One JSON file per finished case, written atomically (a killed run leaves no half part)."""

    def __init__(self, parts_dir: Path) -> None:
        self.dir = Path(parts_dir)
        self.dir.mkdir(parents=True, exist_ok=True)

    def path(self, key: str) -> Path:
        return self.dir / f"{key}.json"

    def get(self, key: str) -> dict[str, Any] | None:
        try:
            return json.loads(self.path(key).read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return None

    def put(self, row: dict[str, Any]) -> None:
        tmp = self.dir / f".{row['key']}.{os.getpid()}.tmp"
        tmp.write_text(json.dumps(row, allow_nan=True))
        os.replace(tmp, self.path(row["key"]))


@dataclass
class RunStats:
    total: int = 0  # distinct cases in the spec
    reused: int = 0  # found in the store
    computed: int = 0  # run now
    failed: int = 0  # failed rows among all
    wall_s: float = 0.0
    case_s: float = 0.0  # sum of the computed cases' own wall times
    dashboard: str = ""
    workers: int = 0
    computed_keys: list[str] = field(default_factory=list)


# ---------------------------------------------------------------- progress


class Progress:
    """A rich bar on a terminal; elsewhere one line every ``every_s`` seconds and at the end."""

    def __init__(self, total: int, done: int, stream=None, every_s: float = 30.0) -> None:
        self.stream = stream or sys.stderr
        self.total, self.done, self.failed = total, done, 0
        self.every_s, self.t0, self.last = every_s, time.monotonic(), time.monotonic()
        self.bar = None
        if self.stream.isatty():
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn, TimeRemainingColumn
            from rich.progress import Progress as RichProgress

            self.bar = RichProgress(TextColumn("cases"), BarColumn(), MofNCompleteColumn(),
                                    TextColumn("{task.fields[f]}"), TimeElapsedColumn(), TimeRemainingColumn(),
                                    console=Console(file=self.stream), transient=False)  # fmt: skip
            self.task = self.bar.add_task("cases", total=total, completed=done, f="")
            self.bar.start()

    def step(self, failed: bool) -> None:
        self.done += 1
        self.failed += failed
        if self.bar is not None:
            self.bar.update(self.task, completed=self.done, f=f"{self.failed} failed" if self.failed else "")
        elif time.monotonic() - self.last >= self.every_s:
            self.line()

    def line(self) -> None:
        self.last = time.monotonic()
        print(f"study: {self.done}/{self.total} cases done, {self.failed} failed, "
              f"{self.last - self.t0:.0f} s", file=self.stream, flush=True)  # fmt: skip

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()
        else:
            self.line()


# ---------------------------------------------------------------- clients

#: the whole connection to a --scheduler (TCP connect, Dask's handshake and its first reply) ends within this
SCHEDULER_TIMEOUT_S = 10.0


class NoScheduler(Exception):
    """No Dask scheduler answers at the address: nothing listens, or something else does (a banner, silence)."""


def check_scheduler(address: str, timeout_s: float | None = None) -> None:
    """Ask ``address`` who it is, the whole exchange under one deadline: a NoScheduler unless a Dask
    scheduler answers. (``Client(address, timeout=...)`` bounds only the TCP connect: a silent peer hangs its
    handshake for ever, and a peer that sends a banner first has it read as a frame length.)"""
    import asyncio

    from distributed.comm import connect
    from distributed.security import Security

    timeout_s = SCHEDULER_TIMEOUT_S if timeout_s is None else timeout_s

    async def ask() -> Any:
        comm = await connect(address, timeout=timeout_s, **Security().get_connection_args("client"))
        try:
            await comm.write({"op": "identity"})
            return await comm.read()
        finally:
            comm.abort()

    try:
        reply = asyncio.run(asyncio.wait_for(ask(), timeout_s))
    except TimeoutError:
        raise NoScheduler(f"no answer within {timeout_s:g} s") from None
    except (OSError, ValueError) as e:  # refused, no route, a name that does not resolve, a protocol Dask lacks
        raise NoScheduler(str(e).splitlines()[0] if str(e) else type(e).__name__) from None
    except Exception as e:  # noqa: BLE001 - whatever a peer that is no Dask makes the handshake raise
        raise NoScheduler(f"what listens there does not speak Dask ({type(e).__name__})") from None
    if not isinstance(reply, dict) or reply.get("type") != "Scheduler":
        kind = reply.get("type") if isinstance(reply, dict) else None
        raise NoScheduler(f"what answers there is a Dask {kind}, not a scheduler" if kind
                                   else "what answers there is not a Dask scheduler")  # fmt: skip


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None) -> Iterator[Any]:
    """A distributed Client: to ``scheduler`` if given, else to an embedded LocalCluster of ``workers``
    single-threaded worker processes (default: one per core)."""
    from distributed import Client, LocalCluster

    if scheduler:
        with Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S:g}s") as client:
            yield client
        return
    n = workers or os.cpu_count() or 1
    dashboard = ":0" if importlib.util.find_spec("bokeh") else None
    # Ctrl-C is this process's to answer, not the workers': a Ctrl-C at the terminal reaches the whole
    # process group, and each worker would print its KeyboardInterrupt traceback. The workers are forked
    # from multiprocessing's fork server, started here with SIGINT ignored: it and every process it forks
    # keep ignoring it, while this process raises KeyboardInterrupt and closes the cluster
    import multiprocessing.forkserver

    import dask

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        multiprocessing.forkserver.ensure_running()
    finally:
        signal.signal(signal.SIGINT, previous)
    with dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"}):
        # a Ctrl-C (or SIGTERM) while the cluster starts is held until it is up (interrupting its start-up
        # leaves half-made nannies that print tracebacks at exit), then delivered to this process's own
        # handler: the KeyboardInterrupt it raises closes the cluster cleanly
        pressed: list[int] = []
        held = (signal.SIGINT, signal.SIGTERM)
        previous = {s: signal.signal(s, lambda signum, _: pressed.append(signum)) for s in held}
        try:
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=dashboard,
                                   silence_logs=logging.ERROR)  # fmt: skip
        finally:
            for s in held:
                signal.signal(s, previous[s])
        with cluster:
            if pressed:
                signal.raise_signal(pressed[0])
            with Client(cluster) as client:
                yield client


def dashboard_of(client) -> str:
    if importlib.util.find_spec("bokeh") is None and client.cluster is not None:
        return "(no dashboard: pip install 'bokeh>=3.1' to get one)"
    return client.dashboard_link


# ---------------------------------------------------------------- the sweep


def run(cases: list[Case], store: Store, client=None, case_fn: CaseFn = run_case, progress: bool = True,
        window: int | None = None) -> tuple[dict[str, dict[str, Any]], RunStats]:  # fmt: skip
    """Every case's row by key: from the store, or computed (on ``client``, or here if None) and stored."""
    t0 = time.perf_counter()
    todo = {c.key: c for c in cases}
    rows: dict[str, dict[str, Any]] = {}
    for key in list(todo):
        row = store.get(key)
        if row is not None:
            rows[key] = row
            del todo[key]
    stats = RunStats(total=len(rows) + len(todo), reused=len(rows))
    bar = Progress(stats.total, stats.reused) if progress else None

    def take(row: dict[str, Any], keep: bool = True) -> None:
        rows[row["key"]] = row
        if keep:
            store.put(row)
        stats.computed += 1
        stats.case_s += float(row.get("wall_time_s", 0.0))
        stats.computed_keys.append(row["key"])
        if bar is not None:
            bar.step(row["status"] != "ok")

    try:
        if client is None:
            stats.workers = 0
            for c in todo.values():
                take(case_fn(c.payload()))
        else:
            stats.dashboard = dashboard_of(client)
            stats.workers = len(client.scheduler_info().get("workers", {}))
            _run_dask(client, list(todo.values()), case_fn, take, window)
    finally:
        if bar is not None:
            bar.close()
    stats.failed = sum(1 for r in rows.values() if r.get("status") != "ok")
    stats.wall_s = time.perf_counter() - t0
    return rows, stats


def _run_dask(client, todo: list[Case], case_fn: CaseFn, take, window: int | None) -> None:
    from distributed import as_completed

    def threads() -> int:
        return sum(w.get("nthreads", 1) for w in client.scheduler_info().get("workers", {}).values()) or 1

    pending = iter(todo)
    run_id = uuid.uuid4().hex[:8]  # this run's task keys: never a stale result of another function
    width = window or 2 * threads() + 2
    by_future = {}

    def submit_one(ac) -> bool:
        c = next(pending, None)
        if c is None:
            return False
        fut = client.submit(case_fn, c.payload(), key=f"case-{c.key}-{run_id}", pure=False)
        by_future[fut.key] = (c, fut)
        ac.add(fut)
        return True

    ac = as_completed()
    for _ in range(width):
        if not submit_one(ac):
            break
    checked = time.monotonic()
    try:
        for fut in ac:
            c, _ = by_future.pop(fut.key)
            if fut.status == "finished":
                take(fut.result())
            else:  # the case never finished (e.g. its worker died too often): a failed row, not stored
                try:
                    err = fut.exception()
                    text = f"{type(err).__name__}: {err}"
                except Exception as e:  # noqa: BLE001 - whatever the future holds, report it
                    text = f"{type(e).__name__}: {e}"
                take({"key": c.key, "status": "failed", "error": text, "wall_time_s": 0.0}, keep=False)
            fut.release()
            if window is None and time.monotonic() - checked > 10.0:
                checked = time.monotonic()
                width = 2 * threads() + 2  # a cluster that scaled up (or whose workers joined late) gets more
            while ac.count() < width and submit_one(ac):
                pass
    except BaseException:
        client.cancel([f for _, f in by_future.values()])
        raise
