"""The program's entry (its console script and ``python -m ground_station``): nothing of the program is imported
before a Ctrl-C is handled (balloon_core.entry)."""

from balloon_core.entry import run


def main() -> int:
    return run("balloon-gs", "ground_station.cli:main")
