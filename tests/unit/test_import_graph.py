"""The packages' modules import each other without a cycle: every import counts (top level, ``TYPE_CHECKING`` and
function level), read with ``ast`` from the sources, so a cycle cannot hide behind a lazy or type-only import."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("runtime", "coordinator", "robot_agent", "inchworm", "swarm_cli")


def modules() -> dict[str, Path]:
    """Every module of the packages: dotted name -> file."""
    found = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imported(name: str, path: Path, known: dict[str, Path]) -> set[str]:
    """The modules of ``known`` that ``name`` imports anywhere in its source (``from m import x``: ``m.x`` if that is a
    module, else ``m``)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parts, base] if base else parts)
            out.update(f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names)
    return {m for m in out if m in known and m != name}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_cycles_are_found() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert cycles(graph) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_relative_and_submodule_imports_resolve(tmp_path: Path) -> None:
    (tmp_path / "pkg").mkdir()
    init, sub = tmp_path / "pkg" / "__init__.py", tmp_path / "pkg" / "sub.py"
    init.write_text("from .sub import thing\n")
    sub.write_text("def f():\n    from pkg import other  # a function-level import counts\n")
    known = {"pkg": init, "pkg.sub": sub, "pkg.other": sub}
    assert imported("pkg", init, known) == {"pkg.sub"}
    assert imported("pkg.sub", sub, known) == {"pkg.other"}


def test_no_import_cycle_among_the_packages() -> None:
    known = modules()
    assert len(known) > 100
    graph = {name: imported(name, path, known) for name, path in known.items()}
    assert cycles(graph) == []


@pytest.mark.parametrize("package", PACKAGES)
def test_no_import_marked_as_working_around_a_cycle(package: str) -> None:
    marked = [f"{path.relative_to(ROOT)}:{n}" for path in (ROOT / package).rglob("*.py")
              for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1) if "import" in line and "(cycle)" in line]
    assert marked == []


def test_the_coordinators_algorithm_core_knows_no_network() -> None:
    """coordinator/ outside coordinator/node/ (selection, localization, executor, plans) imports neither Zenoh nor the
    networked node, so the same core runs in-process, in replay and behind any backend."""
    known = modules()
    core = {name: path for name, path in known.items() if name.startswith("coordinator") and not name.startswith("coordinator.node")}
    assert "coordinator.executor" in core and "coordinator.node.process" in known
    networked = {name: sorted(m for m in imported(name, path, known) if m.startswith(("coordinator.node", "runtime.wire.transport")))
                 for name, path in core.items()}
    zenoh = sorted(name for name, path in core.items() if "zenoh" in {a.split(".")[0] for a in _absolute_imports(path)})
    assert {k: v for k, v in networked.items() if v} == {} and zenoh == []


def _absolute_imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.add(node.module)
    return out
