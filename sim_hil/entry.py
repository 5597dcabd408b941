"""The program's entry (its console script and ``python -m sim_hil``): nothing of the program is imported
before a Ctrl-C is handled (balloon_core.entry)."""

from balloon_core.entry import run


def main() -> int:
    return run("balloon-sim", "sim_hil.cli:main")


def replay() -> int:
    return run("balloon-replay", "sim_hil.replay:main")
