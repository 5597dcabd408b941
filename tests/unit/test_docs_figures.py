"""The numbers the docs quote are what their commands printed (``make docs-figures`` = tools/docs_figures.py
records them in docs/figures.json); one of them recomputed here, cheaply."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))
import docs_figures  # noqa: E402


@pytest.fixture(scope="module")
def record():
    import json

    return json.loads(docs_figures.RECORD.read_text())


def test_the_docs_quote_what_the_commands_printed(record):
    assert docs_figures.check(record) == []


def test_the_record_holds_the_demo_score_and_the_study_tables(record):
    sil = record["sil"]
    assert sil["command"] == "balloon-sil --scenario paper-reference"  # what make demo runs
    assert docs_figures.SCORE.search(sil["score_line"]) and 0.0 < sil["band_rmse_mps"] < 1.0
    rows = [ln for ln in record["study"]["stdout"] if ln.startswith("| 0.92") or ln.startswith("| 1.15")]
    assert len(rows) == 4


def test_the_quick_study_lift_margins_are_recomputed(record):
    """The cheap column: the lift margin of each radius, from the design alone."""
    from dataclasses import replace

    from balloon_core.config import Design, lift_balance

    lines = record["study"]["stdout"]
    header = [c.strip() for c in next(ln for ln in lines if ln.startswith("| balloon.radius_m")).split("|")[1:-1]]
    col = header.index("lift_margin_n")
    rows = [[c.strip() for c in ln.split("|")[1:-1]] for ln in lines if ln.startswith(("| 0.92", "| 1.15"))]
    for row in rows:
        d = Design()
        d = replace(d, balloon=replace(d.balloon, radius_m=float(row[0])))
        assert float(row[col]) == pytest.approx(lift_balance(d)[-1], rel=0.02, abs=0.06)
