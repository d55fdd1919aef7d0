"""The house keeps its layering: each package imports only packages below it, and no two files import
each other (``docs/architecture.md``).

Every module under ``cmudrive/`` is parsed with :mod:`ast`; module-level and function-level imports both
count (a function-level import still runs, only later). Imports under ``if TYPE_CHECKING:`` are left out:
they never run, they only name types for mypy. String class paths resolved at run time (the agent
registry in ``agents/base.py``) are not imports and are not seen here.

``from pkg import name`` is an edge to ``pkg.name`` when that is a module, else to ``pkg``; from a
module outside ``pkg`` it is an edge to ``pkg`` (its ``__init__``) as well, which runs first. (A module
inside ``pkg`` has ``pkg`` initialised already, so that edge would be no circle.)
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import cmudrive

PACKAGE_DIR = Path(cmudrive.__file__).parent

# bottom to top; a package may import those before it (and itself). "core" is the package root
# (cmudrive/__init__.py: the version) and the top-level modules beside it (provenance.py).
LAYERS: tuple[str, ...] = (
    "core",
    "maps",
    "sim",
    "sensors",
    "v2v",
    "agents",
    "bench",
    "data",
    "model",
    "leaderboard",
    "viz",
    "cli",
)

# (importing module, imported module, why): the only imports that run back up; each reason is also in
# the importing module's docstring or at the import
ALLOWED_UPWARD: tuple[tuple[str, str, str], ...] = (
    (
        "cmudrive.data.collector",
        "cmudrive.model.row",
        "one row contract: collection builds the model's input rows with the module the closed-loop agent "
        "uses (DESIGN.md); model.row needs only data.schema, so there is no circle",
    ),
)

# the one circle between files: RoadMap.index builds the LaneIndex lazily (a function-level import in
# maps/model.py) and the index reads the RoadMap it is built from
ALLOWED_CYCLES: tuple[frozenset[str], ...] = (frozenset({"cmudrive.maps.model", "cmudrive.maps.index"}),)


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        parts = ["cmudrive", *path.relative_to(PACKAGE_DIR).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _type_checking_nodes(tree: ast.AST) -> set[int]:
    """ids of the nodes under ``if TYPE_CHECKING:`` (or ``typing.TYPE_CHECKING``)."""
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and ast.unparse(node.test).endswith("TYPE_CHECKING"):
            skip.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return skip


def _package_of(module: str) -> str:
    return module.split(".")[1] if module.count(".") >= 1 and module.split(".")[1] in LAYERS else "core"


def import_graph() -> dict[str, set[str]]:
    """Module -> the ``cmudrive`` modules its imports run."""
    modules = _modules()
    graph: dict[str, set[str]] = defaultdict(set)
    for module, path in modules.items():
        tree = ast.parse(path.read_text(), str(path))
        skip = _type_checking_nodes(tree)
        for node in ast.walk(tree):
            if id(node) in skip:
                continue
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                inside = module == node.module or module.startswith(node.module + ".")
                for alias in node.names:
                    full = f"{node.module}.{alias.name}"
                    targets.append(full if full in modules else node.module)
                    if not inside:
                        targets.append(node.module)
            graph[module].update(t for t in targets if t in modules and t != module)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[frozenset[str]] = []
    for root in sorted(graph):
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
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(frozenset(component))
    return found


def test_every_package_has_a_layer() -> None:
    packages = {p.name for p in PACKAGE_DIR.iterdir() if (p / "__init__.py").exists()}
    assert packages <= set(LAYERS), f"packages without a layer: {sorted(packages - set(LAYERS))}"


def test_imports_only_run_downward() -> None:
    assert len(ALLOWED_UPWARD) <= 3
    rank = {name: k for k, name in enumerate(LAYERS)}
    upward = sorted(
        (module, target)
        for module, targets in import_graph().items()
        for target in targets
        if rank[_package_of(target)] > rank[_package_of(module)]
    )

    def allowed(module: str, target: str) -> bool:  # the allowed module, or its package's __init__
        return any(module == a and (target == b or b.startswith(target + ".")) for a, b, _ in ALLOWED_UPWARD)

    assert [edge for edge in upward if not allowed(*edge)] == []
    gone = [(a, b) for a, b, _ in ALLOWED_UPWARD if (a, b) not in upward]
    assert gone == [], "an allowed upward import is gone: drop it from the list"


def test_allowed_upward_imports_say_why_in_the_importing_module() -> None:
    modules = _modules()
    for module, target, _ in ALLOWED_UPWARD:
        docstring = ast.get_docstring(ast.parse(modules[module].read_text())) or ""
        assert f"imports ``{target}``" in docstring, f"{module}'s docstring must say why it imports {target}"


def test_no_import_cycle_between_files() -> None:
    assert sorted(map(sorted, _cycles(import_graph()))) == sorted(map(sorted, ALLOWED_CYCLES))


def test_the_cycle_finder_sees_a_cycle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [frozenset({"a", "b", "c"})]
