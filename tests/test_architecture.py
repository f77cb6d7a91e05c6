"""The code's shape (issue 15): no import cycles, the library never imports the CLI, small units.

Read from the source with :mod:`ast`, imports inside functions included, so a cycle hidden in a
function body fails here as well.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "facetransfer"
MAX_FUNCTION_LINES = 80
MAX_MODULE_LINES = 900


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _owner(name: str) -> str | None:
    """The module that ``name`` (a module or a name inside one) lives in."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imported(module: str, path: Path) -> set[str]:
    """Modules of this package that ``module`` imports anywhere in its body."""
    base = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            root = ".".join(base[:len(base) - node.level + 1] + [node.module or ""]) \
                if node.level else (node.module or "")
            root = root.rstrip(".")
            names = [f"{root}.{a.name}" if f"{root}.{a.name}" in MODULES else root
                     for a in node.names]
        else:
            continue
        found.update(o for n in names if (o := _owner(n)) and o != module)
    return found


GRAPH = {m: _imported(m, p) for m, p in MODULES.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(root):
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]; counter[0] += 1
        stack.append(root); on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter[0]; counter[0] += 1
                    stack.append(w); on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop(); on.discard(w); comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_cycle_finder_finds_a_planted_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_the_import_graph_is_read():
    # known edges, so that an empty graph cannot pass the tests below
    assert "facetransfer.tensor" in GRAPH["facetransfer.model"]
    assert "facetransfer.cli.stderr" in GRAPH["facetransfer.cli.main"]  # inside a function
    assert "facetransfer.track.result" in GRAPH["facetransfer.track"]  # relative, in __init__


def test_no_import_cycles():
    assert _cycles(GRAPH) == []


def _in_cli(module: str) -> bool:
    return module == "facetransfer.cli" or module.startswith("facetransfer.cli.")


def test_the_library_never_imports_the_cli():
    bad = {m: sorted(d for d in deps if _in_cli(d)) for m, deps in GRAPH.items()
           if not _in_cli(m)}
    assert {m: d for m, d in bad.items() if d} == {}


@pytest.mark.parametrize("module", sorted(MODULES))
def test_units_are_small(module):
    path = MODULES[module]
    text = path.read_text(encoding="utf-8")
    assert len(text.splitlines()) <= MAX_MODULE_LINES, f"{path} has over {MAX_MODULE_LINES} lines"
    long = [(n.name, n.end_lineno - n.lineno + 1) for n in ast.walk(ast.parse(text))
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))
            and n.end_lineno - n.lineno + 1 > MAX_FUNCTION_LINES]
    assert long == []


def test_the_package_docstring_maps_the_library_entry_points():
    """help(facetransfer) named the modules but no function to call: a researcher scripting
    the library had to find obtain_track, plan_transfer or export_track by reading the CLI.
    Every dotted name of the map must resolve."""
    import importlib
    import re

    import facetransfer

    names = re.findall(r"^    (facetransfer(?:\.\w+)+)\s", facetransfer.__doc__, re.M)
    assert {"facetransfer.track.obtain.obtain_track", "facetransfer.transfer.recombine",
            "facetransfer.default_model.load_default_model",
            "facetransfer.export.export_track"} <= set(names)
    for name in names:
        mod, attr = name.rsplit(".", 1)
        assert hasattr(importlib.import_module(mod), attr), name


def test_the_readme_paper_table_names_modules_that_exist():
    """README's "How the code follows the paper" table put the bilateral smoothing of the scans
    (§4.1 of the paper) under §4.2 and named neither its module nor Procrustes': every module
    it names must exist, and every module of correspond be named."""
    import importlib
    import pkgutil
    import re
    from pathlib import Path

    text = (Path(__file__).parents[1] / "README.md").read_text()
    table = text.split("## How the code follows the paper", 1)[1].split("\n## ", 1)[0]
    assert "§4.1 bilateral smoothing" in table
    for row in re.findall(r"^\|[^|\n]*\|([^|\n]*)\|$", table, re.M):
        for pkg, inner in re.findall(r"`(facetransfer(?:\.\w+)*)`(?: \(([^)]*)\))?", row):
            importlib.import_module(pkg)
            for sub in re.findall(r"`(\w+)`", inner):
                importlib.import_module(f"{pkg}.{sub}")
    import facetransfer.correspond as correspond

    row = next(r for r in table.splitlines() if "`facetransfer.correspond`" in r)
    for m in pkgutil.iter_modules(correspond.__path__):
        if m.name not in ("prior", "report", "synthetic"):   # the project's own additions
            assert f"`{m.name}`" in row, m.name
