"""The import graph of pipeline/ and ffviz/: no cycles, and pipeline/ stays free of the viewer and plotting.

Every module is parsed with ``ast`` (nothing is imported), and every import statement counts, also one inside
a function: an import hidden in a function still makes the two modules depend on each other, it only moves
the failure (a partly initialised module) from import time to call time.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("pipeline", "ffviz")


def _modules() -> dict[str, Path]:
    """Dotted module name -> file, for every .py file of PACKAGES (a package's __init__ is the package)."""
    found = {}
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            parts = path.relative_to(REPO).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join(parts)] = path
    return found


def _imported_names(module: str, path: Path) -> set[str]:
    """Every dotted name `module` imports (``import a.b`` -> a.b; ``from a import b`` -> a.b and a)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: strip the module's own name, then level - 1 packages more
                is_package = path.name == "__init__.py"
                anchor = module.split(".")[: len(module.split(".")) - node.level + is_package]
                base = ".".join(anchor + ([base] if base else []))
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
    return names


def import_graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports anywhere in its source (itself excluded)."""
    modules = _modules()
    graph = {}
    for module, path in modules.items():
        targets = set()
        for name in _imported_names(module, path):
            # `from pipeline import metrics` names pipeline.evaluation.metrics; `import pipeline.evaluation.metrics` too
            while name and name not in modules:
                name = name.rpartition(".")[0]
            if name and name != module:
                targets.add(name)
        graph[module] = targets
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle as [a, b, ..., a], or None (depth-first search, white/grey/black colouring)."""
    state: dict[str, int] = {}  # 1 on the current path, 2 finished
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for target in sorted(graph.get(node, ())):
            if state.get(target) == 1:
                return path[path.index(target):] + [target]
            if target not in state:
                cycle = visit(target)
                if cycle:
                    return cycle
        path.pop()
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state:
            cycle = visit(node)
            if cycle:
                return cycle
    return None


def test_the_graph_sees_imports_inside_functions():
    graph = import_graph()
    assert "ffviz.demo" in graph["ffviz.cli"]  # cli dispatches `ffviz demo` with an import in cmd_demo
    assert "pipeline.evaluation.metrics" in graph["ffviz.bench"]  # imported inside input_row
    assert "pipeline.errors" in graph["pipeline.runtime.video_io"]


def test_find_cycle_reports_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


def test_no_import_cycles():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_pipeline_imports_neither_rerun_nor_matplotlib():
    modules = _modules()
    offenders = sorted(
        f"{module} imports {name}"
        for module, path in modules.items() if module.split(".")[0] == "pipeline"
        for name in _imported_names(module, path) if name.split(".")[0] in ("rerun", "matplotlib")
    )
    assert not offenders, offenders


MAX_MODULE_DOCSTRING_LINES = 25  # issue 21: what, which equations, invariants, why; measurements live in docs/


def long_module_docstrings(root: Path, limit: int = MAX_MODULE_DOCSTRING_LINES) -> dict[str, int]:
    """File (relative to root's parent) -> line count, for every module under ``root`` whose docstring runs past
    ``limit`` lines (``ast.get_docstring``: indentation cleaned, the text between the quotes)."""
    found = {}
    for path in sorted(root.rglob("*.py")):
        docstring = ast.get_docstring(ast.parse(path.read_text(), filename=str(path)))
        if docstring and len(docstring.splitlines()) > limit:
            found[str(path.relative_to(root.parent))] = len(docstring.splitlines())
    return found


def test_long_module_docstrings_are_found(tmp_path):
    package = tmp_path / "pkg"
    package.mkdir()
    (package / "short.py").write_text('"""' + "\n".join(["line"] * 25) + '"""\n')
    (package / "long.py").write_text('"""' + "\n".join(["line"] * 26) + '"""\nx = 1\n')
    assert long_module_docstrings(package) == {"pkg/long.py": 26}


def test_module_docstrings_in_pipeline_stay_short():
    too_long = long_module_docstrings(REPO / "pipeline")
    assert not too_long, f"module docstrings over {MAX_MODULE_DOCSTRING_LINES} lines (move measurements to docs/): {too_long}"
