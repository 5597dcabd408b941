"""A program's ``main`` run in process: its exit code (``SystemExit`` included) and what it wrote to stderr."""

from __future__ import annotations

from collections.abc import Callable


def run_main(main: Callable[[list[str]], int], argv: list[str], capsys) -> tuple[int, str]:
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    return code, capsys.readouterr().err
