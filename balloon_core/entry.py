"""How every program starts (its console script and ``python -m``, through its package's ``entry`` module): a Ctrl-C
while the program's modules are still importing (its first fraction of a second: numpy, pymavlink) ends it as one a
moment later does, one line and exit 130, not Python's traceback. The standard library only, so that nothing of the
program is imported before it; the program is named by its package, as a string."""

from __future__ import annotations

import importlib
import sys


def run(prog: str, target: str) -> int:
    """Import ``target`` (``module:function``) and call it; a Ctrl-C during the import, or one the program has not
    handled yet (its options still parsing, its --help still printing), is exit 130 with one line."""
    module, _, function = target.partition(":")
    try:
        main = getattr(importlib.import_module(module), function)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted (Ctrl-C) while starting", file=sys.stderr)
        return 130
    try:
        return main()
    except KeyboardInterrupt:
        print(f"{prog}: interrupted (Ctrl-C)", file=sys.stderr)
        return 130

