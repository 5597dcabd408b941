"""The shipped study files (examples/*.toml) are what the docs tell users to run: each parses and every case's
design passes the programs' own validation, so a renamed key or a refused value fails here, not on a user's
machine."""

from __future__ import annotations

from pathlib import Path

import pytest

from study.spec import load_spec, validate_designs

EXAMPLES = sorted((Path(__file__).resolve().parents[2] / "examples").glob("*.toml"))


def test_there_are_examples():
    assert len(EXAMPLES) >= 3


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.name)
def test_an_example_study_file_parses_and_its_designs_validate(path):
    spec = load_spec(str(path))
    validate_designs(spec)
    assert spec.cases()
