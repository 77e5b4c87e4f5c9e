"""No import circle in the product, imports written inside functions counted (ARCHITECTURE.md, issue 35).

The graph is grimp's (the library under import-linter), which records an import wherever it is written, a
function body included. Imports under ``if TYPE_CHECKING:`` are left out: they never run. An import also
runs the ``__init__`` of every package above the module it names, so each edge is extended to those
packages (the circle ``runview -> sample.model`` then ``sample/__init__ -> sample.load -> journal`` is real
even though no module names ``core.sample`` itself).

An import inside a function is for a heavy optional dependency only, never to hide a loop.
"""

from __future__ import annotations

import ast
from pathlib import Path

import grimp
import networkx as nx

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("core", "drivers", "aeni_console")

# third-party packages heavy enough to load only on the path that needs them (plots, dashboards, the
# distributed bench, the model's numerics); an import of anything else belongs at the module's top
HEAVY_OPTIONAL = frozenset(
    {
        "apprise",
        "dask",
        "distributed",
        "gpytorch",
        "joblib",
        "matplotlib",
        "pandas",
        "plotext",
        "pyarrow",
        "scipy",
        "textual",
        "textual_plotext",
        "torch",
    }
)

# files the `spec` branch rewrites in this same session (issue 35's RunSpec and compose): their imports
# inside functions are hoisted when the two branches are merged (then this set is emptied)
PENDING_SPEC_MERGE: frozenset[str] = frozenset()
# The command modules import the product (core, drivers, aeni_console) inside their handlers, so building
# the parser, `aeni --help`, loads no torch (tests/test_cli_startup.py). Nothing below them imports them (the
# layers contract in pyproject.toml: testkit > cli > the rest), so such an import hides no circle below.
COMMAND_LAYER = "aeni_console/cli/"


def _ancestors(module: str) -> list[str]:
    parts = module.split(".")
    return [".".join(parts[:k]) for k in range(1, len(parts))]


def _runtime_graph() -> nx.DiGraph:
    graph = grimp.build_graph(*PACKAGES, exclude_type_checking_imports=True, cache_dir=None)
    g = nx.DiGraph()
    ours = [m for m in graph.modules if m.split(".")[0] in PACKAGES]
    g.add_nodes_from(ours)
    for importer in ours:
        for imported in graph.find_modules_directly_imported_by(importer):
            if imported.split(".")[0] not in PACKAGES or imported == importer:
                continue
            g.add_edge(importer, imported)
            # importing a.b.c runs a/__init__ and a/b/__init__ first (those not already running)
            for pkg in _ancestors(imported):
                if pkg != importer and pkg not in _ancestors(importer):
                    g.add_edge(importer, pkg)
    return g


def test_no_import_circle() -> None:
    g = _runtime_graph()
    assert len(g) > 100  # the whole product was read
    circles = [sorted(c) for c in nx.strongly_connected_components(g) if len(c) > 1]
    shown = []
    for c in circles:
        cycle = nx.find_cycle(g.subgraph(c))
        shown.append(f"{len(c)} modules: " + " -> ".join([a for a, _ in cycle] + [cycle[0][0]]))
    assert not circles, "import circles:\n" + "\n".join(shown)


def _imports_inside_functions(path: Path) -> list[tuple[int, str]]:
    """(line, top-level package) of each import written inside a function body."""
    found: list[tuple[int, str]] = []

    def walk(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if in_function and isinstance(child, ast.Import):
                found.extend((child.lineno, a.name.split(".")[0]) for a in child.names)
            elif in_function and isinstance(child, ast.ImportFrom):
                top = "." if child.level else (child.module or "").split(".")[0]
                found.append((child.lineno, top))
            walk(child, in_function or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda))

    walk(ast.parse(path.read_text(encoding="utf-8")), False)
    return found


def test_imports_inside_functions_are_heavy_optional_only() -> None:
    files = sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))
    assert len(files) > 100
    bad = []
    for path in files:
        rel = path.relative_to(ROOT).as_posix()
        if rel in PENDING_SPEC_MERGE:
            continue
        bad += [
            f"{rel}:{line} imports {top}"
            for line, top in _imports_inside_functions(path)
            if top not in HEAVY_OPTIONAL and not (rel.startswith(COMMAND_LAYER) and top in PACKAGES)
        ]
    assert not bad, "imports inside functions of light or own modules (move them to the top):\n" + "\n".join(
        bad
    )


def test_the_checks_see_a_circle_and_a_hidden_import(tmp_path: Path) -> None:
    """The two checks above can fail: a package-init circle is found, a function's import is seen."""
    g = nx.DiGraph([("p.a", "p.b"), ("p.b", "p"), ("p", "p.a")])
    assert [c for c in nx.strongly_connected_components(g) if len(c) > 1]
    src = tmp_path / "m.py"
    src.write_text(
        "import os\n\ndef f():\n    from core import plan\n    import matplotlib.pyplot\n    return plan\n"
    )
    assert _imports_inside_functions(src) == [(4, "core"), (5, "matplotlib")]
    assert _ancestors("core.sample.model") == ["core", "core.sample"]
