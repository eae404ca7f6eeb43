"""The layout's rules, read from the source's imports (also those inside functions):

- the runtime (``roadbev_core``, ``msg_bridge``, ``roadbev_ros``: what a car runs) never imports
  the lab (``roadbev_lab``) or the command line (``roadbev_cli``);
- the lab never imports the command line;
- the project's modules import each other without a circle;
- the config is a leaf: it imports nothing of the project above it.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
RUNTIME = ("roadbev_core", "msg_bridge", "roadbev_ros")
LAB = ("roadbev_lab",)
CLI = ("roadbev_cli",)
PACKAGES = RUNTIME + LAB + CLI


def _module_name(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for pkg in PACKAGES for p in sorted((REPO / pkg).rglob("*.py"))}


def _imported(name: str, path: Path) -> Iterator[str]:
    """Every dotted name ``name``'s module imports, anywhere in it (absolute and relative)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                module = ".".join([*base, node.module] if node.module else base)
            else:
                module = node.module or ""
            yield module
            yield from (f"{module}.{alias.name}" for alias in node.names)


def _graph() -> dict[str, set[str]]:
    """module -> the project modules it imports (a name resolved to the longest module prefix)."""
    modules = _modules()
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        deps: set[str] = set()
        for imported in _imported(name, path):
            while imported and imported not in modules:
                imported = imported.rpartition(".")[0]
            if imported and imported != name:
                deps.add(imported)
        graph[name] = deps
    return graph


def _top(module: str) -> str:
    return module.partition(".")[0]


def test_the_layout_sees_every_package() -> None:
    graph = _graph()
    assert {_top(m) for m in graph} == set(PACKAGES)
    assert "roadbev_core.pipeline" in graph["roadbev_ros.node"]


@pytest.mark.parametrize(("lower", "upper"), [(RUNTIME, LAB + CLI), (LAB, CLI)])
def test_no_arrow_points_up(lower: tuple[str, ...], upper: tuple[str, ...]) -> None:
    wrong = sorted(f"{m} -> {d}" for m, deps in _graph().items() if _top(m) in lower
                   for d in deps if _top(d) in upper)
    assert not wrong, "imports from below into the layers above:\n" + "\n".join(wrong)


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
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
                    work.append((child, iter(sorted(graph.get(child, ())))))
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
                    out.append(sorted(component))
    return out


def test_cycles_are_found() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_circle() -> None:
    circles = _cycles(_graph())
    assert not circles, "modules that import each other in a circle:\n" + "\n".join(" <-> ".join(c) for c in circles)


def test_the_config_is_a_leaf() -> None:
    """The config imports only the errors, the backend names (a leaf itself) and its own modules:
    what a component must judge is judged by the component (roadbev_core.pipeline.check_config)."""
    graph = _graph()
    allowed = {"roadbev_core.errors", "roadbev_core.backend_plugins"}
    wrong = sorted(f"{m} -> {d}" for m, deps in graph.items() if m.startswith("roadbev_core.config")
                   for d in deps if d not in allowed and not d.startswith("roadbev_core.config"))
    assert not wrong, "the config imports above itself:\n" + "\n".join(wrong)
    assert graph["roadbev_core.backend_plugins"] <= {"roadbev_core.errors"}


def test_ray_is_an_optional_extra_of_the_lab() -> None:
    """Ray (``pip install .[fleet]``) is never imported by the runtime, and by the lab and the
    command line only inside a function (a car's install has no Ray; a command without --ray
    never loads it)."""
    runtime, at_top = [], []
    for name, path in _modules().items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            if not any(n == "ray" or n.startswith("ray.") for n in names):
                continue
            if _top(name) in RUNTIME:
                runtime.append(name)
            elif node in tree.body:
                at_top.append(name)
    assert not runtime, f"the runtime imports ray: {runtime}"
    assert not at_top, f"ray imported at module level (it is an optional extra): {at_top}"
