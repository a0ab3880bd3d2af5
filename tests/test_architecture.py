"""The shape docs/architecture.md describes: each package imports only the packages below it, no module or class
name is defined twice, no function runs past 60 lines, and `pipeline/` holds stage functions only."""

import ast
import collections
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "uqdrive"
BELOW_SAFETY = {"policy", "sim", "models", "uq", "data"}
LAYERS = {  # package → the project packages it may import (root modules are open to all)
    "uq": set(),
    "sim": set(),
    "data": set(),
    "models": {"data", "uq"},
    "policy": {"sim", "models", "uq", "data"},
    "safety": BELOW_SAFETY,
    "replay": {"safety"} | BELOW_SAFETY,
    "avoid": {"safety"} | BELOW_SAFETY,
    "envelope": {"safety"} | BELOW_SAFETY,
    "analysis": {"avoid", "envelope", "safety"} | BELOW_SAFETY,
    "report": {"analysis", "avoid", "envelope", "replay", "safety"} | BELOW_SAFETY,
}
WING_PARTS = {"plan", "cells", "figure"}  # a wing's standard parts share names: envelope/plan.py, avoid/plan.py
TOOLS = {"bench", "tools"}  # commands and benchmarks: use any part; nothing imports them


def modules() -> dict[Path, ast.Module]:
    return {p: ast.parse(p.read_text()) for p in sorted(PACKAGE.rglob("*.py"))}


def imported_packages(tree: ast.Module) -> set[str]:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("uqdrive."):
            names.add(node.module.split(".")[1])
        elif isinstance(node, ast.Import):
            names |= {a.name.split(".")[1] for a in node.names if a.name.startswith("uqdrive.")}
    return names


def test_packages_import_only_the_packages_below_them():
    packages = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    upward = []
    for path, tree in modules().items():
        here = path.relative_to(PACKAGE).parts[0]
        if here in LAYERS:
            for name in imported_packages(tree) & packages - LAYERS[here] - {here}:
                upward.append(f"{path.relative_to(PACKAGE)} imports uqdrive.{name}")
        elif path.parent == PACKAGE:  # root utilities
            for name in imported_packages(tree) & ({"pipeline", "report", "analysis"} | TOOLS):
                upward.append(f"{path.relative_to(PACKAGE)} imports uqdrive.{name}")
    assert not upward, "\n".join(upward)


def test_no_module_or_class_name_is_defined_twice():
    names, classes = collections.defaultdict(list), collections.defaultdict(list)
    for path, tree in modules().items():
        rel = path.relative_to(PACKAGE)
        if path.name != "__init__.py" and path.stem not in WING_PARTS:
            names[path.stem].append(str(rel))
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                classes[node.name].append(str(rel))
    names.update({p.name: [*names[p.name], f"{p.name}/"] for p in PACKAGE.iterdir() if p.is_dir()})
    assert not {k: v for k, v in names.items() if len(v) > 1}
    assert not {k: v for k, v in classes.items() if len(v) > 1}


def test_no_function_runs_past_60_lines():
    long = [
        f"{path.relative_to(PACKAGE)}:{node.name} ({node.end_lineno - node.lineno + 1} lines)"
        for path, tree in modules().items()
        for node in ast.walk(tree)
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno + 1 > 60
    ]
    assert not long, "\n".join(long)


def test_pipeline_holds_one_stage_module_per_stage_and_each_run_returns_a_dataclass():
    stages = sorted(p.name for p in (PACKAGE / "pipeline").glob("*.py") if p.name != "__init__.py")
    assert all(name.endswith("_stage.py") for name in stages), stages
    plain = []
    for path in (PACKAGE / "pipeline").glob("*_stage.py"):
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.FunctionDef) and node.name.startswith("run_"):
                returns = ast.unparse(node.returns) if node.returns else ""
                if returns.startswith(("dict", "list", "None")) or not returns:
                    plain.append(f"{path.name}:{node.name} -> {returns or '?'}")
    assert not plain, plain


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_modules(path: Path, tree: ast.Module, known: set[str]) -> set[str]:
    """Every uqdrive module ``tree`` imports, at any depth (inside functions and ``if TYPE_CHECKING`` too): ``from
    uqdrive.x import name`` is the module ``uqdrive.x.name`` where that is one, else ``uqdrive.x``."""
    here = module_name(path).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = (
                ".".join(package[: len(package) - node.level + 1] + [node.module or ""]) if node.level else node.module
            )
            base = base.rstrip(".")
            found |= {f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names}
    return found & known


def import_circles() -> list[list[str]]:
    """The import circles among uqdrive's modules (each once, from its smallest module), depth-first."""
    trees = modules()
    known = {module_name(path) for path in trees}
    graph = {module_name(path): sorted(imported_modules(path, tree, known)) for path, tree in trees.items()}
    circles, done = set(), set()

    def walk(node: str, stack: list[str]) -> None:
        for nxt in graph[node]:
            if nxt in stack:
                circle = stack[stack.index(nxt) :]
                first = circle.index(min(circle))
                circles.add(tuple(circle[first:] + circle[:first]))
            elif nxt not in done:
                walk(nxt, [*stack, nxt])
        done.add(node)

    for start in sorted(graph):
        if start not in done:
            walk(start, [start])
    return [list(c) for c in sorted(circles)]


def test_no_import_circle_even_through_deferred_imports():
    assert not import_circles(), "\n".join(" → ".join([*c, c[0]]) for c in import_circles())


WORLD_TYPES = {  # the worlds (`uqdrive.sim.world.World`), their locations' configs and their lanes, and the bodies
    "World",
    "DrivingEnv",
    "GymWorld",
    "ScenarioConfig",
    "GymWorldConfig",
    "ScenarioGeometry",
    "DrivenPath",
    "Scene",
}


def test_no_code_outside_sim_asks_which_world_it_has():
    asked = [
        f"{path.relative_to(PACKAGE)}:{node.lineno} {ast.unparse(node)}"
        for path, tree in modules().items()
        if path.relative_to(PACKAGE).parts[0] != "sim"
        for node in ast.walk(tree)
        if isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id in ("isinstance", "issubclass")
        and len(node.args) == 2
        and {n.id if isinstance(n, ast.Name) else getattr(n, "attr", "") for n in ast.walk(node.args[1])} & WORLD_TYPES
    ]
    assert not asked, "\n".join(asked)
