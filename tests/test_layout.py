"""Package layout: the core (drill_env) never imports the controllers (drill_env.agents, the
project's agents/ folder), nothing imports the controllers by a top-level name ``agents``
(which other distributions install), no module imports another that imports it back (lazy
and type-only imports count), and the registry is the one list of controllers the figures
and the command line draw on."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
# each package's folder and its import name: the controllers live in agents/, imported as
# drill_env.agents (drill_env/agents links there in a checkout; the wheel puts them there)
PACKAGES = {"drill_env": "drill_env", "agents": "drill_env.agents"}
CONTROLLERS = PACKAGES["agents"]


def _modules() -> dict[str, Path]:
    out = {}
    for folder, name in PACKAGES.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = list(path.relative_to(ROOT / folder).with_suffix("").parts)
            if folder == "drill_env" and parts[0] == "agents":
                continue  # the controllers, by their own folder
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join([name, *parts])] = path
    return out


def _imports(module: str, path: Path, known: set[str]) -> set[str]:
    """Every module of ``known`` that ``module`` imports anywhere in its source."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parent + ([base] if base else []))
            names = [base] + [f"{base}.{a.name}" for a in node.names]
        else:
            continue
        for name in names:
            while name and name not in known:
                name = name.rpartition(".")[0]
            if name and name != module and not module.startswith(name + "."):
                found.add(name)
    return found


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    return {m: _imports(m, p, set(mods)) for m, p in mods.items()}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as a path, or None (depth-first search with colours)."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                return stack[stack.index(n) :] + [n]
            if n not in state and (found := visit(n)):
                return found
        state[m] = 2
        stack.pop()
        return None

    for m in sorted(graph):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_the_cycle_finder_finds_a_cycle():
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


def test_relative_and_lazy_imports_are_edges():
    graph = _graph()
    assert "drill_env.analysis.plots" in graph["drill_env.analysis.diagram"]  # lazy, in .plot()
    assert "drill_env.analysis.equilibria" in graph["drill_env.analysis.continuation"]


def test_no_import_cycles():
    assert _cycle(_graph()) is None


def _is_controllers(module: str) -> bool:
    return module == CONTROLLERS or module.startswith(CONTROLLERS + ".")


def test_the_module_list_has_both_packages_once():
    mods = _modules()
    assert {
        "drill_env.cli",
        "drill_env.agents",
        "drill_env.agents.learning.rl",
        "drill_env.agents.commands.train",
    } <= set(mods)
    assert not any(m == "agents" or m.startswith("agents.") for m in mods)
    assert len(set(mods.values())) == len(mods)


def test_the_core_does_not_import_the_controllers():
    graph = _graph()
    # the controllers' imports of each other and of the core are edges under their import names
    assert {"drill_env.agents.controllers.base", "drill_env.params"} <= graph[
        "drill_env.agents.controllers.gains"
    ]
    offenders = {m: sorted(d for d in deps if _is_controllers(d)) for m, deps in graph.items()}
    assert {m: d for m, d in offenders.items() if not _is_controllers(m) and d} == {}


def _top_level_agents_imports(path: Path) -> list[str]:
    """Where ``path`` imports a top-level ``agents`` (absolute imports; lazy ones included)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            names = [node.module or ""]
        else:
            continue
        found += [f"{path.relative_to(ROOT)}:{node.lineno} {n}" for n in names if n.split(".")[0] == "agents"]
    return found


def test_the_top_level_scan_finds_an_import_of_agents(tmp_path, monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    path = tmp_path / "m.py"
    path.write_text(
        "import agents.rl\nfrom drill_env.agents import rl\nfrom . import agents\n"
        "def f():\n    from agents import registry\n"
    )
    assert _top_level_agents_imports(path) == ["m.py:1 agents.rl", "m.py:5 agents"]


def test_nothing_imports_a_top_level_agents():
    # the controllers are drill_env.agents: a top-level agents is another distribution's
    # package, or this one's folder imported a second time under another name
    paths = [
        p
        for folder in ("drill_env", "agents", "tests", "benchmarks")
        for p in sorted((ROOT / folder).rglob("*.py"))
    ]
    assert len(paths) > 100
    assert [hit for p in paths for hit in _top_level_agents_imports(p)] == []


def test_the_controllers_compile_nothing():
    # the numba cache is keyed on the core's sources only (drill_env/_cache.py)
    graph = _graph()
    found = {}
    for module, path in _modules().items():
        if _is_controllers(module):
            tree = ast.parse(path.read_text())
            names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
            names += [
                n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.level == 0
            ]
            if any(n.split(".")[0] == "numba" for n in names) or "drill_env._numba" in graph[module]:
                found[module] = path
    assert found == {}


def test_controller_commands_come_from_the_agents_package():
    from drill_env.cli import COMMAND_PACKAGES, app

    assert COMMAND_PACKAGES.index("drill_env.commands") < COMMAND_PACKAGES.index("drill_env.agents.commands")
    names = {c.name or c.callback.__name__ for c in app.registered_commands}
    assert {"simulate", "bifurcation", "benchmark", "tune", "train"} <= names
    modules = {c.name: c.callback.__module__ for c in app.registered_commands if c.name}
    assert {modules[n] for n in ("benchmark", "tune", "train")} == {
        "drill_env.agents.commands.benchmark",
        "drill_env.agents.commands.tune",
        "drill_env.agents.commands.train",
    }


def test_every_controller_has_its_own_style():
    from drill_env.agents.evaluation.benchmark import _MARKERS
    from drill_env.agents.evaluation.robustness import COLORS
    from drill_env.agents.registry import CONTROLLERS, controller_style

    assert set(COLORS) == set(_MARKERS) == set(CONTROLLERS)
    styles = [controller_style(c) for c in CONTROLLERS]
    assert len(set(s.colour for s in styles)) == len(styles)
    assert len(set(s.marker for s in styles)) == len(styles)


@pytest.mark.parametrize("added", [("td3",), ("td3", "ddpg", "tqc")])
def test_a_controller_added_to_the_list_gets_a_style_of_its_own(monkeypatch, added):
    from drill_env.agents import registry

    monkeypatch.setattr(registry, "CONTROLLERS", registry.CONTROLLERS + added)
    styles = [registry.controller_style(c) for c in registry.CONTROLLERS]
    assert len(set(s.colour for s in styles)) == len(styles)
    assert len(set(s.marker for s in styles)) == len(styles)
    assert registry.controller_style("not_a_controller") == ("gray", "o")


def test_commands_from_an_entry_point_and_a_missing_package(monkeypatch):
    import importlib.metadata

    import typer

    from drill_env import cli

    class EntryPoint:
        def load(self):
            def register(app):
                @app.command("hello")
                def hello() -> None:
                    typer.echo("hello")

            return register

    seen = []

    def entry_points(group):
        seen.append(group)
        return [EntryPoint()]

    app = typer.Typer()
    monkeypatch.setattr(cli, "app", app)
    monkeypatch.setattr(cli, "COMMAND_PACKAGES", (*cli.COMMAND_PACKAGES, "no_such_package.commands"))
    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
    cli._register_commands()
    names = {c.name for c in app.registered_commands}
    assert seen == [cli.ENTRY_POINT_GROUP]
    assert {"bifurcation", "benchmark", "tune", "train", "hello"} <= names


def _package_edges(graph: dict[str, set[str]], src: str, dst: str) -> dict[str, list[str]]:
    """Imports from modules of package ``src`` into modules of package ``dst``."""
    inside = lambda m, p: m == p or m.startswith(p + ".")  # noqa: E731
    return {m: sorted(d for d in deps if inside(d, dst)) for m, deps in graph.items() if inside(m, src)}


def test_the_package_edge_finder_finds_an_edge():
    graph = {"p.a": {"q.b", "p.c"}, "p.c": set(), "q.b": set()}
    assert _package_edges(graph, "p", "q") == {"p.a": ["q.b"], "p.c": []}


def test_identification_and_discrepancy_sit_side_by_side_on_the_recordings_layer():
    graph = _graph()
    recordings, identify, discrepancy = "drill_env.recordings", "drill_env.identify", "drill_env.discrepancy"
    # both read recordings through the one layer ...
    assert recordings + ".dataset" in graph["drill_env.identify.identification"]
    assert recordings + ".equation_error" in graph["drill_env.discrepancy.workflow"]
    # ... which knows neither of them, and neither imports the other
    for src, dst in (
        (recordings, identify),
        (recordings, discrepancy),
        (identify, discrepancy),
        (discrepancy, identify),
    ):
        found = {m: d for m, d in _package_edges(graph, src, dst).items() if d}
        assert found == {}, f"{src} imports {dst}: {found}"
