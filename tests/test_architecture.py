"""The import graph of pipeline/ and ffviz/: every import follows the layers docs/architecture.md writes down, there
are no cycles, and pipeline/ stays free of the viewer and plotting.

Every module is parsed with ``ast`` (nothing is imported), and every import statement counts, also one inside
a function: an import hidden in a function still makes the two modules depend on each other, it only moves
the failure (a partly initialised module) from import time to call time.
"""

from __future__ import annotations

import ast
import fnmatch
import re
import textwrap
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("pipeline", "ffviz")
ARCHITECTURE = REPO / "docs" / "architecture.md"


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
    assert "pipeline.evaluation.metrics" in graph["ffviz.bench.command"]  # imported inside input_row
    assert "pipeline.errors" in graph["pipeline.runtime.video_reader"]


def test_find_cycle_reports_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


def test_no_import_cycles():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


# ---------------------------------------------------------------------------------------------- layers


@dataclass(frozen=True)
class Layer:
    name: str
    modules: tuple[str, ...]  # dotted names, or patterns with *
    may_import: tuple[str, ...]  # names of lower layers


def read_layers(text: str) -> list[Layer]:
    """The rows of the table under the "## Layers" heading of ``text``, bottom to top."""
    section = re.search(r"^## Layers\n(.*?)(?=^## |\Z)", text, re.M | re.S)
    assert section, "docs/architecture.md has no '## Layers' section"
    layers = []
    for line in section.group(1).splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if not line.startswith("|") or len(cells) != 3 or cells[0] in ("layer", "") or set(cells[0]) <= {"-"}:
            continue
        below = () if cells[2] == "nothing" else tuple(name.strip() for name in cells[2].split(","))
        layers.append(Layer(cells[0], tuple(re.findall(r"`([^`]+)`", cells[1])), below))
    return layers


def _packages() -> set[str]:
    return {module for module, path in _modules().items() if path.name == "__init__.py"}


def layer_of(module: str, layers: list[Layer]) -> str | None:
    """The layer naming ``module`` exactly, else the one whose pattern matches it (None: no row names it)."""
    exact = [layer.name for layer in layers if module in layer.modules]
    matched = exact or [layer.name for layer in layers
                        if any("*" in pattern and fnmatch.fnmatchcase(module, pattern) for pattern in layer.modules)]
    assert len(matched) <= 1, f"{module} is named by the layers {matched}"
    return matched[0] if matched else None


def reachable(layers: list[Layer]) -> dict[str, set[str]]:
    """Layer -> the layers its modules may import: itself, the ones its row names, and theirs in turn."""
    allowed: dict[str, set[str]] = {}
    for layer in layers:  # bottom to top, so every named layer is already complete
        allowed[layer.name] = {layer.name}.union(*(allowed[below] for below in layer.may_import))
    return allowed


def layer_violations(graph: dict[str, set[str]], layers: list[Layer], exempt: set[str] = frozenset()) -> list[str]:
    """One line, "a (its layer) imports b (its layer)", for every import of ``graph`` against ``layers``
    (``exempt``: modules that belong to no layer and any may import, the empty package __init__s)."""
    allowed = reachable(layers)
    found = []
    for module in sorted(set(graph) - exempt):
        own = layer_of(module, layers)
        for target in sorted(graph[module] - exempt):
            theirs = layer_of(target, layers)
            if own is None or theirs is None or theirs not in allowed[own]:
                found.append(f"{module} ({own}) imports {target} ({theirs})")
    return found


LAYERS = read_layers(ARCHITECTURE.read_text())


def test_the_layers_are_read_bottom_to_top():
    names = [layer.name for layer in LAYERS]
    assert names[0] == "foundation" and names[-1] == "ffviz cli" and len(names) == len(set(names))
    for index, layer in enumerate(LAYERS):
        assert set(layer.may_import) <= set(names[:index]), f"{layer.name} may only import layers below it"


def test_every_module_has_a_layer_and_every_row_a_module():
    modules = set(_modules()) - _packages()
    unnamed = sorted(module for module in modules if layer_of(module, LAYERS) is None)
    assert not unnamed, f"modules no row of the layer table names: {unnamed}"
    stale = [f"{layer.name}: {pattern}" for layer in LAYERS for pattern in layer.modules
             if not any(fnmatch.fnmatchcase(module, pattern) for module in modules)]
    assert not stale, f"layer table entries that name no module: {stale}"


def test_layer_violations_are_found():
    layers = read_layers("""## Layers
| layer | modules | may import |
|---|---|---|
| base | `p.errors` | nothing |
| stages | `p.stages.*` | base |
| runtime | `p.runtime.*` | base |
| types | `p.results` | stages |
| hook | `p.runtime.hook` | types |
| top | `p.run` | hook, runtime |
""")
    graph = {"p.errors": set(), "p.stages.a": {"p.errors", "p.stages.b", "p"}, "p.stages.b": {"p.runtime.io"},
             "p.runtime.io": {"p.errors"}, "p.runtime.hook": {"p.results", "p.runtime.io"},
             "p.results": {"p.stages.a"}, "p.run": {"p.runtime.hook", "p.runtime.io", "p.errors", "p.stages.a"},
             "p": set()}
    assert layer_violations(graph, layers, exempt={"p"}) == [
        "p.runtime.hook (hook) imports p.runtime.io (runtime)",  # the exact name beats the runtime pattern
        "p.stages.b (stages) imports p.runtime.io (runtime)",  # stages and runtime do not see each other
    ]
    graph["p.errors"] = {"p.run"}  # upwards
    assert layer_violations(graph, layers, exempt={"p"})[0] == "p.errors (base) imports p.run (top)"
    graph["p.errors"] = {"p.loose"}  # a module no row names
    assert layer_violations(graph, layers, exempt={"p"})[0] == "p.errors (base) imports p.loose (None)"


def test_package_inits_import_nothing_of_the_project():
    """What lets the layers leave the packages out: importing one brings in none of the project's modules."""
    graph = import_graph()
    assert {package: graph[package] for package in _packages() if graph[package]} == {}


def test_no_import_against_the_layers():
    violations = layer_violations(import_graph(), LAYERS, exempt=_packages())
    assert not violations, "imports against the layers of docs/architecture.md:\n" + "\n".join(violations)


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


MAX_FUNCTION_LINES = 80  # a function fits on a screen (argument tables may be data instead)
# Functions still over the limit, each to be split; an entry that no longer is over it fails the test below, so
# the list only shrinks.
def long_functions(root: Path, limit: int = MAX_FUNCTION_LINES) -> dict[str, int]:
    """Lines (signature to last line) by "file: function" (file relative to root's parent, a method as
    Class.name) of every function under ``root`` longer than ``limit``; a nested one is counted on its own too."""
    found = {}

    def visit(node: ast.AST, path: Path, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = child.end_lineno - child.lineno + 1
                if lines > limit:
                    found[f"{path.relative_to(root.parent)}: {prefix}{child.name}"] = lines
                visit(child, path, f"{prefix}{child.name}.")
            else:
                visit(child, path, f"{prefix}{child.name}." if isinstance(child, ast.ClassDef) else prefix)

    for path in sorted(root.rglob("*.py")):
        visit(ast.parse(path.read_text(), filename=str(path)), path, "")
    return found


def test_long_functions_are_found(tmp_path):
    package = tmp_path / "pkg"
    package.mkdir()
    body = "\n".join(["x = 1"] * 79)
    fits = "def fits():\n" + textwrap.indent(body, "    ")  # 80 lines
    long = "class C:\n    def long(self):\n" + textwrap.indent(body + "\ny = 2", "        ")  # 81 lines
    (package / "a.py").write_text(f"{fits}\n\n\n{long}\n")
    assert long_functions(package) == {"pkg/a.py: C.long": 81}


def test_functions_fit_on_a_screen():
    too_long = {**long_functions(REPO / "pipeline"), **long_functions(REPO / "ffviz")}
    assert not too_long, f"functions over {MAX_FUNCTION_LINES} lines: {too_long}"
