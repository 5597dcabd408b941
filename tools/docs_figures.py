"""The figures and numbers the docs quote, regenerated from the commands that make them (``make docs-figures``).

``python tools/docs_figures.py`` runs, from the repository root:
- ``balloon-sil`` on defaults (what ``make demo`` runs): its figure becomes ``docs/sil.png`` (the README's image),
  its score line is recorded;
- ``balloon-study examples/quick-study.toml --workers 2``: its tables replace the example in ``docs/study.md``;
- ``python -m postflight.logs tests/data/FILE --estimate`` on the two PX4 multicopter logs: the last wind and
  accuracy the estimator gives, which ``docs/usage.md`` quotes;
- ``python -m tools.web_screenshot``: the browser ground station's picture, ``docs/web.png`` (skipped, the old
  picture kept, without chromium);
- ``python -m benchmarks.bench_speed``: its table replaces the speed tables of ``docs/estimator.md`` and
  ``docs/porting.md`` (about 90 s; the figures are this machine's at that moment);
and writes what they printed to ``docs/figures.json``. ``--check`` (and ``tests/unit/test_docs_figures.py``)
compare the docs against that record without running anything: exit 1 and the differences if they disagree.
``--only sil|study|ulog|web|speed`` reruns one part (the others keep their record).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
RECORD = DOCS / "figures.json"
SIL_PNG = DOCS / "sil.png"
WEB_PNG = DOCS / "web.png"
STUDY_MD = DOCS / "study.md"
USAGE_MD = DOCS / "usage.md"
STUDY_SPEC = "examples/quick-study.toml"
STUDY_PROMPT = f"$ balloon-study {STUDY_SPEC} --out results/quick --workers 2"
# the logs docs/usage.md quotes, and the first words of the paragraph that quotes each
SPEED_PROMPT = "$ .venv/bin/python -m benchmarks.bench_speed"
SPEED_DOCS = (DOCS / "estimator.md", DOCS / "porting.md")  # each quotes the table after SPEED_PROMPT
ULOGS = {"pyulog-sample.ulg": "- PX4 AUAV-X2.1 multicopter flight", "pyulog-sample_log_small.ulg": "- PX4 CubeOrange"}
SCORE = re.compile(
    r"band RMSE \(<0\.05 Hz\) (?P<band_rmse_mps>[-\d.]+) m/s, skill (?P<band_skill>[-\d.]+) \| raw RMSE "
    r"(?P<raw_rmse_mps>[-\d.]+) m/s \| mean speed [-\d.]+ vs [-\d.]+ m/s \((?P<speed_error_pct>[-+\d.]+) %\) \| "
    r"direction error (?P<direction_error_deg>[-+\d.]+) deg \| horiz_accuracy [-\d.]+ m/s \(actual error / accuracy "
    r"(?P<error_ratio>[-\d.]+)\)"
)
ESTIMATE = re.compile(r"\|\s*(?P<speed>[\d.]+)\|\s*m/s\s+accuracy\s+(?P<accuracy>[\d.]+) m/s")


def _run(*args: str) -> str:
    r = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"docs_figures: {' '.join(args)} failed (exit {r.returncode}):\n{r.stderr[-2000:]}")
    return r.stdout


def sil() -> dict:
    """``balloon-sil`` on defaults: the figure and the score it prints."""
    with tempfile.TemporaryDirectory() as tmp:
        out = _run("-m", "sil", "--outdir", tmp)
        shutil.copyfile(Path(tmp) / "paper-reference-seed1.png", SIL_PNG)
    line = next(ln for ln in out.splitlines() if ln.startswith("score: "))
    m = SCORE.search(line)
    if m is None:
        raise SystemExit(f"docs_figures: cannot read the score line: {line}")
    loss = next(ln for ln in out.splitlines() if ln.startswith("balloon-sil: ") and "lost" in ln)
    return {"command": "balloon-sil --scenario paper-reference", "score_line": line, "loss_line": loss,
            "png_sha256": hashlib.sha256(SIL_PNG.read_bytes()).hexdigest(),
            **{k: float(v) for k, v in m.groupdict().items()}}  # fmt: skip


def web() -> dict:
    """``balloon-gs web``'s picture (tools/web_screenshot.py); the record kept as it was without chromium."""
    r = subprocess.run([sys.executable, "-m", "tools.web_screenshot", "--out", str(WEB_PNG)], cwd=ROOT,
                       capture_output=True, text=True)  # fmt: skip
    if r.returncode == 2:
        print(f"docs_figures: web skipped: {r.stderr.strip()}", file=sys.stderr)
        old = json.loads(RECORD.read_text()) if RECORD.exists() else {}
        return old.get("web", {})
    if r.returncode != 0:
        raise SystemExit(f"docs_figures: tools/web_screenshot.py failed (exit {r.returncode}):\n{r.stderr[-2000:]}")
    return {"command": "python -m tools.web_screenshot", "png_sha256": hashlib.sha256(WEB_PNG.read_bytes()).hexdigest()}


def study() -> dict:
    """The quick study's tables, as ``balloon-study`` prints them."""
    with tempfile.TemporaryDirectory() as tmp:
        out = _run("-m", "study", STUDY_SPEC, "--out", tmp, "--workers", "2")
    lines = out.rstrip("\n").splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("sweep "))
    end = next(i for i, ln in enumerate(lines) if " distinct cases: " in ln)  # then where it wrote: a temporary dir
    return {"command": STUDY_PROMPT[2:], "stdout": lines[start : end + 1]}


def ulog() -> dict:
    """The estimator's last wind and accuracy on each PX4 log docs/usage.md quotes."""
    rec = {}
    for name in ULOGS:
        out = _run("-m", "postflight.logs", f"tests/data/{name}", "--estimate")
        last = [m for m in map(ESTIMATE.search, out.splitlines()) if m][-1]
        rec[name] = {"speed_mps": float(last["speed"]), "accuracy_mps": float(last["accuracy"])}
    return rec


def speed() -> dict:
    """The speed table, as ``benchmarks.bench_speed`` prints it."""
    out = _run("-m", "benchmarks.bench_speed")
    return {"command": SPEED_PROMPT[2:], "stdout": out.rstrip("\n").splitlines()}


def study_block(text: str, prompt: str = STUDY_PROMPT) -> list[str]:
    """The lines of a doc's example after its prompt (docs/study.md's quick study by default), up to the
    closing fence."""
    lines = text.splitlines()
    i = lines.index(prompt) + 1
    j = lines.index("```", i)
    return lines[i:j]


def write_study(lines: list[str], path: Path = STUDY_MD, prompt: str = STUDY_PROMPT) -> None:
    """Replace the lines after ``prompt`` up to the closing fence (``study_block``) with ``lines``."""
    text = path.read_text()
    old = text.splitlines()
    i = old.index(prompt) + 1
    j = old.index("```", i)
    path.write_text("\n".join(old[:i] + lines + old[j:]) + ("\n" if text.endswith("\n") else ""))


def ulog_phrases(rec: dict) -> dict[str, list[str]]:
    """What each log's paragraph in docs/usage.md must say: its wind and accuracy, as the record rounds them."""
    return {ULOGS[n]: [f"{v['speed_mps']:.1f} m/s", f"±{v['accuracy_mps']:.1f} m/s"] for n, v in rec.items()}


def check(record: dict) -> list[str]:
    """The docs against the record: what disagrees (empty: all agree)."""
    bad = []
    if hashlib.sha256(SIL_PNG.read_bytes()).hexdigest() != record["sil"]["png_sha256"]:
        bad.append("docs/sil.png is not the figure balloon-sil made (run make docs-figures)")
    if study_block(STUDY_MD.read_text()) != record["study"]["stdout"]:
        bad.append("docs/study.md: the quick-study tables are not what balloon-study printed")
    web_rec = record.get("web", {})
    if web_rec and (not WEB_PNG.exists() or hashlib.sha256(WEB_PNG.read_bytes()).hexdigest() != web_rec["png_sha256"]):
        bad.append("docs/web.png is not the picture tools/web_screenshot.py made (run make docs-figures)")
    for path in SPEED_DOCS:
        if study_block(path.read_text(), SPEED_PROMPT) != record["speed"]["stdout"]:
            bad.append(f"docs/{path.name}: the speed table is not what benchmarks.bench_speed printed")
    usage = USAGE_MD.read_text()
    for start, phrases in ulog_phrases(record["ulog"]).items():
        para = usage[usage.index(start) :].split("\n- ", 1)[0]
        bad += [f"docs/usage.md: '{start}' does not say {p}" for p in phrases if p not in para]
    return bad


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare the docs with docs/figures.json, run nothing")
    ap.add_argument("--only", choices=("sil", "study", "ulog", "web", "speed"), action="append",
                    help="rerun only this part")
    args = ap.parse_args(argv)
    record = json.loads(RECORD.read_text()) if RECORD.exists() else {}
    if not args.check:
        for part, make in (("sil", sil), ("study", study), ("ulog", ulog), ("web", web), ("speed", speed)):
            if args.only is None or part in args.only:
                print(f"docs_figures: {part} ...", file=sys.stderr, flush=True)
                record[part] = make()
        write_study(record["study"]["stdout"])
        for path in SPEED_DOCS:
            write_study(record["speed"]["stdout"], path, SPEED_PROMPT)
        RECORD.write_text(json.dumps(record, indent=1, ensure_ascii=False) + "\n")
        print(f"docs_figures: {record['sil']['score_line']}")
    bad = check(record)
    for b in bad:
        print(f"docs_figures: {b}", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
