"""The program's entry (its console script and ``python -m firmware_py``): nothing of the program is imported
before a Ctrl-C is handled (balloon_core.entry)."""

from balloon_core.entry import run


def main() -> int:
    return run("balloon-fw", "firmware_py.cli:main")
