"""The layers hold (docs/architecture.md): the import graph, read from the source (every import,
also those inside functions), has no cycle, and no package imports one above it or beside it."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("balloon_core", "firmware_py", "sim_hil", "ground_station", "postflight", "sil", "study")
# what each package may import of the others
ALLOWED = {
    "balloon_core": set(),
    "firmware_py": {"balloon_core"},
    "postflight": {"balloon_core", "firmware_py"},
    "sim_hil": {"balloon_core", "firmware_py"},  # firmware_py: the [filter] section a scenario may set
    "ground_station": {"balloon_core", "firmware_py", "postflight"},
    "sil": {"balloon_core", "firmware_py", "sim_hil", "ground_station", "postflight"},
    "study": set(PACKAGES) - {"study"},
}
# the estimator: the portable unit (what a C port covers)
ESTIMATOR = "firmware_py.estimator"
ESTIMATOR_MAY_IMPORT = {"math", "numpy", "dataclasses", "typing", "__future__", "balloon_core.atmosphere",
                        "balloon_core.rotation", "balloon_core.config"}  # fmt: skip


def modules() -> dict[str, set[str]]:
    """module name -> the modules it imports (absolute names)."""
    graph = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            name = ".".join(p for p in rel.parts if p != "__init__")
            deps = set()
            tree = ast.parse(path.read_text())
            for node in ast.walk(tree):  # type-only imports (under ``if TYPE_CHECKING``) are no dependency
                if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING":
                    node.body = []
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    deps |= {a.name for a in node.names}
                elif isinstance(node, ast.ImportFrom) and node.module:
                    base = node.module
                    deps.add(base)
                    deps |= {f"{base}.{a.name}" for a in node.names}
            graph[name] = deps
    return graph


GRAPH = modules()


def internal(deps: set[str]) -> set[str]:
    return {d for d in deps if d in GRAPH}


def test_no_package_imports_one_it_must_not():
    bad = []
    for mod, deps in GRAPH.items():
        top = mod.split(".")[0]
        for d in deps:
            other = d.split(".")[0]
            if other in PACKAGES and other != top and other not in ALLOWED[top]:
                bad.append(f"{mod} -> {d}")
    assert not bad, bad


def test_import_graph_has_no_cycle():
    state: dict[str, int] = {}
    cycles = []

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for d in sorted(internal(GRAPH[m])):
            if d == m or d.startswith(m + "."):
                continue  # a package's __init__ is not a cycle with its own modules
            if state.get(d) == 1:
                cycles.append(path[path.index(d):] + [d] if d in path else path + [d])
            elif d not in state:
                visit(d, path + [d])
        state[m] = 2

    for m in sorted(GRAPH):
        if m not in state:
            visit(m, [m])
    assert not cycles, cycles[:3]


def test_the_estimator_is_a_portable_unit():
    """It imports nothing outside itself but plain maths and the core's design, atmosphere and
    rotations: no I/O, no MAVLink, no other program."""
    bad = []
    for mod, deps in GRAPH.items():
        if not mod.startswith(ESTIMATOR):
            continue
        for d in deps:
            if d.startswith(ESTIMATOR) or d in ESTIMATOR_MAY_IMPORT or d.split(".")[0] in ("math", "numpy"):
                continue
            if any(d.startswith(a + ".") for a in ESTIMATOR_MAY_IMPORT):
                continue
            bad.append(f"{mod} -> {d}")
    assert not bad, bad


def test_the_check_sees_a_forbidden_import():
    assert "balloon_core" in GRAPH and len(GRAPH) > 40
    graph = {**GRAPH, "balloon_core.config": GRAPH["balloon_core.config"] | {"sim_hil.wind"}}
    top = "balloon_core"
    assert any(d.split(".")[0] not in ALLOWED[top] | {top} and d.split(".")[0] in PACKAGES
               for d in graph["balloon_core.config"])  # fmt: skip
