"""The import graph of the packages: acyclic, and the command line is a leaf.

Every ``import`` statement of every module (also those inside functions: a deferred import is still a
dependency) is an edge between modules of the packages on the data path.  The graph must have no cycle,
and no module outside ``flexstab/commands/`` and ``flexstab/cli.py`` -- no library module, script or
benchmark -- may import ``flexstab.commands`` (the library never calls its own command line).
Written from the language reference's import rules (absolute and relative ``from`` imports), not from
any code under test; each rule is shown to reject a tree that breaks it.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("mbs_models", "linearize", "stability", "taguchi", "validation", "flexstab")
#: Modules that may import the command modules: the command line itself.
COMMAND_LINE = ("flexstab.commands", "flexstab.cli")


def _modules(root: Path, packages) -> dict[str, Path]:
    mods = {}
    for pkg in packages:
        for f in sorted((root / pkg).rglob("*.py")):
            parts = list(f.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = f
    return mods


def _imported(f: Path, package: str) -> list[str]:
    """Every name ``f`` imports (``from a import b`` gives ``a`` and ``a.b``), relative ones resolved."""
    names = []
    for node in ast.walk(ast.parse(f.read_text(), str(f))):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = parts[: len(parts) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            names += [mod] + [f"{mod}.{a.name}" for a in node.names]
    return names


def import_graph(root: Path, packages=PACKAGES) -> dict[str, set[str]]:
    """Module -> modules of ``packages`` it imports (an import of a module's own ancestor package is
    not an edge: the package is already being imported when its submodule runs)."""
    mods = _modules(root, packages)

    def resolve(name: str):
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for m, f in mods.items():
        package = m if f.name == "__init__.py" else m.rpartition(".")[0]
        targets = {resolve(n) for n in _imported(f, package)}
        graph[m] = {t for t in targets if t and t != m and not m.startswith(t + ".")}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan's algorithm, iterative)."""
    index: dict = {}
    low: dict = {}
    on_stack: set = set()
    stack: list = []
    out = []
    counter = 0
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in graph:
                    continue
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
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
                        out.append(sorted(comp))
    return out


def command_importers(root: Path, packages=PACKAGES, extra_dirs=("scripts", "benchmarks"), graph=None) -> list[str]:
    """Modules and scripts outside the command line that import ``flexstab.commands``."""
    bad = [m for m, targets in (graph if graph is not None else import_graph(root, packages)).items()
           if not m.startswith(COMMAND_LINE) and any(t.startswith("flexstab.commands") for t in targets)]
    for d in extra_dirs:
        for f in sorted((root / d).glob("*.py")) if (root / d).is_dir() else ():
            if any(n == "flexstab.commands" or n.startswith("flexstab.commands.") for n in _imported(f, "")):
                bad.append(str(f.relative_to(root)))
    return bad


@pytest.fixture(scope="module")
def graph():
    return import_graph(ROOT)


def test_the_import_graph_is_acyclic(graph):
    assert "flexstab.study" in graph and "flexstab.stages" in graph["flexstab.study"]  # the graph is read
    assert cycles(graph) == []


def test_only_the_command_line_imports_the_commands(graph):
    assert command_importers(ROOT, graph=graph) == []


def _write(root: Path, files: dict) -> None:
    for name, body in files.items():
        p = root / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(body)


def test_a_cycle_through_a_deferred_import_is_found(tmp_path):
    """Rejects the shape this graph once had: a module importing, inside a function, a module that
    imports it back at the top (study -> commands.chart -> study), and a relative import cycle."""
    _write(tmp_path, {
        "flexstab/__init__.py": "",
        "flexstab/study.py": "def f():\n    from flexstab.commands.chart import make\n",
        "flexstab/commands/__init__.py": "",
        "flexstab/commands/chart.py": "from flexstab.study import f\n",
        "flexstab/a.py": "from . import b\n",
        "flexstab/b.py": "from .a import x\n",
        "flexstab/c.py": "import flexstab\n",  # its own package: not an edge
    })
    found = cycles(import_graph(tmp_path, ("flexstab",)))
    assert sorted(found) == [["flexstab.a", "flexstab.b"], ["flexstab.commands.chart", "flexstab.study"]]
    assert command_importers(tmp_path, ("flexstab",), extra_dirs=()) == ["flexstab.study"]


def test_a_script_importing_a_command_is_found(tmp_path):
    _write(tmp_path, {"flexstab/__init__.py": "", "flexstab/cli.py": "import flexstab.commands.tune\n",
                      "flexstab/commands/__init__.py": "", "flexstab/commands/tune.py": "",
                      "scripts/run.py": "from flexstab.commands import tune\n"})
    assert command_importers(tmp_path, ("flexstab",)) == ["scripts/run.py"]
