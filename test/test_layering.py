"""The package's layering, checked on its import graph (ast of every module, lazy imports too).

`uq/` is a generic library at the bottom (it imports nothing of the package but `errors`), only
`nodes/` imports rclpy, `fleet/` never imports `review/` and `standards/` imports neither (the
EN 13848 limits both apply live in `standards/`), and no two modules of the package import each
other, directly or through others.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / 'railgsa_ros'


def module_name(path: Path) -> str:
    """Dotted name of a module file of the package (a package's ``__init__`` is the package)."""
    parts = list(path.relative_to(PACKAGE.parent).with_suffix('').parts)
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def imported(path: Path, modules: set[str]) -> set[str]:
    """Every name ``path`` imports, anywhere in the file: a package module when the import
    names one (``from railgsa_ros.uq import pce`` -> ``railgsa_ros.uq.pce``), else the
    imported module's dotted name as written."""
    name = module_name(path)
    package = name.split('.') if path.name == '__init__.py' else name.split('.')[:-1]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ''
            if node.level:
                base = '.'.join(package[:len(package) - node.level + 1] + [base] * bool(base))
            for alias in node.names:
                full = f'{base}.{alias.name}'
                found.add(full if full in modules else base)
    return found


def import_graph() -> dict[str, set[str]]:
    """Module -> every name it imports (package modules resolved as in :func:`imported`)."""
    paths = {module_name(path): path for path in PACKAGE.rglob('*.py')}
    return {name: imported(path, set(paths)) for name, path in paths.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for other in graph[node] & graph.keys():
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = stack[stack.index(node):]
            del stack[stack.index(node):]
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_cycle_finder_sees_a_cycle_through_three_modules() -> None:
    graph = {'a': {'b'}, 'b': {'c'}, 'c': {'a', 'd'}, 'd': set(), 'e': {'e'}}
    assert cycles(graph) == [['a', 'b', 'c']]


def test_uq_imports_nothing_of_the_package_but_errors() -> None:
    graph = import_graph()
    wrong = {name: sorted(target for target in targets if target.startswith('railgsa_ros')
                          and not target.startswith('railgsa_ros.uq')
                          and target != 'railgsa_ros.errors')
             for name, targets in graph.items() if name.startswith('railgsa_ros.uq')}
    assert not {name: targets for name, targets in wrong.items() if targets}


def test_only_nodes_import_rclpy() -> None:
    graph = import_graph()
    wrong = sorted(name for name, targets in graph.items()
                   if not name.startswith('railgsa_ros.nodes')
                   and any(target.split('.')[0] == 'rclpy' for target in targets))
    assert not wrong


def _imports_of(graph: dict[str, set[str]], section: str, forbidden: tuple[str, ...]
                ) -> dict[str, list[str]]:
    """Modules of ``section`` (a subpackage) that import a module of a ``forbidden`` one."""
    wrong = {name: sorted(t for t in targets
                          if any(t == f'railgsa_ros.{f}' or t.startswith(f'railgsa_ros.{f}.')
                                 for f in forbidden))
             for name, targets in graph.items() if name.startswith(f'railgsa_ros.{section}')}
    return {name: targets for name, targets in wrong.items() if targets}


def test_the_import_rule_finder_sees_a_forbidden_import() -> None:
    graph = {'railgsa_ros.fleet.a': {'railgsa_ros.review.limits', 'numpy'},
             'railgsa_ros.fleet.b': {'railgsa_ros.reviewer'}}
    assert _imports_of(graph, 'fleet', ('review',)) == {
        'railgsa_ros.fleet.a': ['railgsa_ros.review.limits']}


def test_fleet_never_imports_the_review() -> None:
    assert _imports_of(import_graph(), 'fleet', ('review',)) == {}


def test_standards_import_neither_the_review_nor_the_fleet() -> None:
    assert _imports_of(import_graph(), 'standards', ('review', 'fleet', 'nodes')) == {}


def test_no_import_cycle_between_package_modules() -> None:
    assert cycles(import_graph()) == []
