"""The library's import graph has no circle, function-local imports included (a local import that closes a circle
only hides it: the two modules still cannot be understood, moved or tested apart)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "src"


def _modules() -> dict[str, Path]:
    mods = {}
    for f in (ROOT / "simeval").rglob("*.py"):
        parts = list(f.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        mods[".".join(parts)] = f
    return mods


def import_graph() -> dict[str, set[str]]:
    """{module: the simeval modules it imports anywhere in its file}; `from a.b import c` counts a.b, and a.b.c when
    c is a module."""
    mods = _modules()
    edges: dict[str, set[str]] = {m: set() for m in mods}
    for m, f in mods.items():
        package = m.split(".") if f.name == "__init__.py" else m.split(".")[:-1]
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
                names = [base, *(f"{base}.{a.name}" for a in node.names)]
            else:
                continue
            edges[m].update(n for n in names if n in mods and n != m)
    return edges


def circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The graph's strongly connected components of more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        found.append(sorted(comp))
    return found


def test_the_circle_finder_finds_a_known_circle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"d", "f"}, "f": {"e"}}
    assert sorted(circles(graph)) == [["a", "b", "c"], ["e", "f"]]
    assert circles({"a": {"b"}, "b": set()}) == []


def test_the_library_imports_no_circle():
    edges = import_graph()
    assert "simeval.sim.tasks.splits" in edges["simeval.pipelines.base"]  # the parser sees local imports
    assert circles(edges) == []


def floors(edges: dict[str, set[str]]) -> dict[str, set[str]]:
    """The graph between the library's floors: its top-level packages and modules (simeval.sim, simeval.results)."""
    def floor(m: str) -> str:
        return ".".join(m.split(".")[:2])

    out: dict[str, set[str]] = {floor(m): set() for m in edges}
    for m, targets in edges.items():
        out[floor(m)].update(floor(t) for t in targets if floor(t) != floor(m))
    return out


def test_floors_are_read_from_the_modules_graph():
    graph = {"simeval.sim.env": {"simeval.sim.core.world", "simeval.episodes.episode"}, "simeval.sim.core.world": set(),
             "simeval.episodes.episode": {"simeval.errors"}, "simeval.errors": set()}
    assert floors(graph) == {"simeval.sim": {"simeval.episodes"}, "simeval.episodes": {"simeval.errors"},
                             "simeval.errors": set()}


def test_no_arrow_runs_back_up_between_the_librarys_floors():
    """No package imports one that imports it back, local imports included (e.g. the episode store importing the
    quality run's bundle format while the quality run reads the store): the floors stack up in one order."""
    assert circles(floors(import_graph())) == []


def test_the_bundle_format_imports_no_quality_run_and_loggers_import_no_report():
    edges = import_graph()
    assert not {m for m in edges["simeval.measures.quality.bundle"] if m.startswith("simeval.measures.quality")}
    assert not {m for m in edges["simeval.loggers"] if m.startswith(("simeval.writing", "simeval.measures.quality"))}


def test_no_test_file_imports_another():
    """Shared helpers live in tests/helpers.py and fixtures in conftest.py: a test file that imports another runs
    that file's module-level code and ties the two together."""
    tests = Path(__file__).resolve().parent
    names = {f.stem for f in tests.glob("test_*.py")}
    offenders = []
    for f in sorted(tests.glob("*.py")):
        for node in ast.walk(ast.parse(f.read_text(encoding="utf-8"))):
            mods = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module] if isinstance(node, ast.ImportFrom) and node.module else []
            offenders += [f"{f.name} imports {m}" for m in mods if m in names]
    assert offenders == []
