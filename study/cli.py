"""balloon-study: design sweeps, the simulator and the estimator per case, on Dask.

    balloon-study SPEC.toml --out DIR [--workers N | --scheduler tcp://HOST:PORT] [--paper]
                  [--sweep NAME ...] [--seeds N] [--duration S] [--no-plots] [--quiet]

Writes DIR/cases.parquet and DIR/cases.csv (one row per case), DIR/summary.csv (mean and worst over the
seeds), DIR/plots/*.png, and keeps every finished case in DIR/parts/ (a rerun reuses them). ``--paper``
runs the paper's study (the spec shipped as examples/paper-study.toml) instead of SPEC.toml.
Exit 0 done (failed cases are rows, not errors), 2 a user error (one line), 130 interrupted (Ctrl-C), 143
terminated (SIGTERM: answered as Ctrl-C is)."""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from dataclasses import replace
from importlib import resources
from pathlib import Path

from balloon_core import userargs
from balloon_core.config import ConfigError
from balloon_core.userargs import UserError, require_extra


class UsageError(Exception):
    pass


class Terminated(KeyboardInterrupt):
    """SIGTERM, answered as Ctrl-C is: the workers stopped, the finished cases kept; exit 143."""


def _terminate(signum, frame) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a second SIGTERM ends the process at once
    raise Terminated


def _exit_code(e: KeyboardInterrupt) -> int:
    return 128 + signal.SIGTERM if isinstance(e, Terminated) else 130


def max_workers() -> int:
    """The most --workers: single-threaded processes that each hold a core while a case runs, so more than a
    few per core only time-share the cores (and each costs ~100 MB of memory); a bigger cluster is --scheduler."""
    return 4 * (os.cpu_count() or 1)


class Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, exit 2 (argparse prints usage too)
        raise UsageError(message)


def parse_args(argv):
    ap = Parser(prog="balloon-study", description=__doc__.split("\n")[0])
    ap.add_argument("spec", nargs="?", help="the study file (TOML); not needed with --paper")
    ap.add_argument("--out", required=True, help="output directory (created; parts/ in it are reused)")
    where = ap.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, help="LocalCluster worker processes (default: one per core; at most "
                       "4 per core); 0 = no Dask, run the cases in this process")  # fmt: skip
    where.add_argument("--scheduler", type=userargs.scheduler_address,
                       help="address of a running Dask scheduler, e.g. tcp://10.0.0.5:8786")  # fmt: skip
    ap.add_argument("--paper", action="store_true", help="the paper's study (Figs. 6-12 + tether and wind axes)")
    ap.add_argument("--seeds", type=int, help="override the spec's seeds with 1..N")
    ap.add_argument("--duration", type=userargs.duration, help="override the spec's duration_s")
    ap.add_argument("--sweep", action="append", metavar="NAME", help="run only this sweep of the spec (repeatable)")
    ap.add_argument("--no-plots", action="store_true")
    ap.add_argument("--quiet", action="store_true", help="no progress on stderr")
    return ap.parse_args(argv)


def paper_spec_text() -> str:
    return resources.files("study").joinpath("data/paper-study.toml").read_text()


def load(args):
    import tomllib

    from study.spec import load_spec, parse_spec

    if args.paper:
        if args.spec:
            raise UsageError("give SPEC.toml or --paper, not both")
        spec = parse_spec(tomllib.loads(paper_spec_text()))
    elif not args.spec:
        raise UsageError("a study file is required (or --paper)")
    else:
        if not Path(args.spec).is_file():
            raise UsageError(f"study file not found: {args.spec}")
        spec = load_spec(args.spec)
    if args.sweep:
        names = [sw.name for sw in spec.sweeps]
        for n in args.sweep:
            if n not in names:
                raise UsageError(f"--sweep {n}: no such sweep; the spec has {', '.join(names)}")
        kept = tuple(sw for sw in spec.sweeps if sw.name in args.sweep)
        spec = replace(spec, sweeps=kept, axis_names=tuple(dict.fromkeys(a.name for sw in kept for a in sw.axes)))
    if args.seeds is not None:
        from study.spec import MAX_CASES

        if not 1 <= args.seeds <= MAX_CASES:  # before the seeds are made
            raise UsageError(f"--seeds must be 1 .. {MAX_CASES} (the most cases of a study), got {args.seeds}")
        spec = replace(spec, seeds=tuple(range(1, args.seeds + 1)))
    if args.duration is not None:
        from study.spec import MIN_SCORED_S

        if args.duration - spec.start_s < MIN_SCORED_S:
            raise UsageError(f"--duration must exceed start_s ({spec.start_s:g} s) by {MIN_SCORED_S:g} s")
        spec = replace(spec, duration_s=float(args.duration))
    from study.spec import check_size

    check_size(spec)  # --seeds can make a spec too big
    return spec


def main(argv: list[str] | None = None) -> int:
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _terminate) if main_thread else None
    previous_int = userargs.ctrl_c_raises() if main_thread else None  # also when started in the background
    try:
        return _main(argv)
    except KeyboardInterrupt as e:  # before the sweep started (while parsing, validating, starting the cluster)
        print(f"balloon-study: {'terminated' if isinstance(e, Terminated) else 'interrupted'}", file=sys.stderr)
        return _exit_code(e)
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)
            signal.signal(signal.SIGINT, previous_int)


def _main(argv: list[str] | None) -> int:
    try:
        args = parse_args(argv)
        require_extra("study")
        if args.workers is not None and not 0 <= args.workers <= max_workers():
            raise UsageError(f"--workers must be 0 .. {max_workers()} (4 per core; a bigger cluster is "
                             f"--scheduler), got {args.workers}")  # fmt: skip
        if not args.out:
            raise UsageError("--out: empty output path")
        out = Path(args.out)
        _check_out(args, out)  # the one rule for output options, before any work
        spec = load(args)
        if args.scheduler:
            _check_scheduler(args.scheduler)
        made = [p for p in (out, out / "parts") if not p.exists()]  # nothing is made before this point
        out.mkdir(parents=True, exist_ok=True)
    except (UsageError, ConfigError, UserError) as e:
        print(f"balloon-study: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"balloon-study: error: {e.strerror or e}: {e.filename or args.out}", file=sys.stderr)
        return 2
    try:
        return run(spec, out, args)
    except KeyboardInterrupt as e:
        what = "terminated" if isinstance(e, Terminated) else "interrupted"
        print(f"balloon-study: {what}; the finished cases are kept in {out / 'parts'}: run the same "
              "command again to resume", file=sys.stderr)  # fmt: skip
        return _exit_code(e)
    except SchedulerUnreachable as e:  # it answered the check, then not the client
        for p in reversed(made):  # what this run made, if it is still empty
            try:
                p.rmdir()
            except OSError:
                pass
        print(f"balloon-study: error: no Dask scheduler at {args.scheduler}: {e}", file=sys.stderr)
        return 2


def _check_out(args, out: Path) -> None:
    """--out is a directory that can be written (or made), and what the study writes in it is not the
    study file (``userargs.check_outputs``)."""
    if os.path.realpath(out) == "/proc" or os.path.realpath(out).startswith("/proc/"):
        raise UsageError(f"--out {out}: cannot be written (under /proc)")
    try:
        userargs.output_dir(str(out))
    except argparse.ArgumentTypeError as exc:
        raise UsageError(f"--out {exc}") from None
    for name in ("parts", "plots"):  # the directories the study keeps in it
        if (out / name).exists() and not (out / name).is_dir():
            raise UsageError(f"--out {out}: {out / name} is not a directory (the study keeps its {name} there)")
        used = not (name == "plots" and args.no_plots)
        if used and (out / name).is_dir() and not os.access(out / name, os.W_OK | os.X_OK):
            raise UsageError(f"--out {out}: {out / name} is not writable (the study keeps its {name} there)")
    if out.is_dir():  # (a directory still to be made holds no input)
        userargs.check_outputs({"SPEC": args.spec},
                               {f"--out ({name})": str(out / name) for name in ("cases.parquet", "cases.csv",
                                                                               "summary.csv")})  # fmt: skip


def _check_scheduler(address: str) -> None:
    from study import engine

    try:
        engine.check_scheduler(address)
    except engine.NoScheduler as e:
        raise UsageError(f"no Dask scheduler at {address}: {e}") from None


class SchedulerUnreachable(Exception):
    pass


def run(spec, out: Path, args) -> int:
    from study import engine, results

    cases = spec.cases()
    store = engine.Store(out / "parts")
    n_unique = len({c.key for c in cases})
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr, flush=True))  # noqa: E731
    say(f"balloon-study: {len(spec.sweeps)} sweep(s), {len(cases)} cases ({n_unique} distinct), "
        f"{len(spec.seeds)} seed(s), {spec.duration_s:g} s each")  # fmt: skip
    if args.workers == 0:
        rows, stats = engine.run(cases, store, None, progress=not args.quiet)
    else:
        connected = False
        try:
            with engine.dask_client(args.workers, args.scheduler) as client:
                connected = True
                workers = len(client.scheduler_info().get("workers", {}))
                say(f"balloon-study: {workers} worker(s), dashboard {engine.dashboard_of(client)}")
                rows, stats = engine.run(cases, store, client, progress=not args.quiet)
        except (OSError, TimeoutError, ValueError) as e:  # ValueError: an address Dask cannot parse (foo://...)
            if connected or not args.scheduler:
                raise
            raise SchedulerUnreachable(str(e).splitlines()[0] if str(e) else type(e).__name__) from None
    case_rows, summ = results.write(out, spec, cases, rows)
    plots = [] if args.no_plots else _plots(spec, case_rows, summ, out)
    for line in results.format_summary(spec, summ):
        print(line)
    print(f"{stats.total} distinct cases: {stats.computed} computed, {stats.reused} reused, {stats.failed} failed; "
          f"{stats.wall_s:.1f} s wall, {stats.case_s:.1f} s in cases")  # fmt: skip
    print(f"wrote {out / 'cases.parquet'}, {out / 'cases.csv'}, {out / 'summary.csv'}"
          + (f", {len(plots)} plots in {out / 'plots'}" if plots else ""))  # fmt: skip
    return 0


def _plots(spec, case_rows, summ, out):
    from study.plots import write_plots

    return write_plots(spec, case_rows, summ, out)


if __name__ == "__main__":
    sys.exit(main())
