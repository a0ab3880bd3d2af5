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


def policy_and_recipe_classes(trees: dict[Path, ast.Module]) -> tuple[dict[str, Path], dict[str, Path]]:
    """The classes that drive (``reset`` with ``act`` or ``act_batch``, or a subclass of one), and the recipes (a
    ``build(self, control_hz)``: what a job builds its policy from), by name, with the file each is defined in."""
    policies, recipes, bases = {}, {}, {}
    for path, tree in trees.items():
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                methods = {f.name: f for f in node.body if isinstance(f, ast.FunctionDef)}
                build = methods.get("build")
                if "reset" in methods and {"act", "act_batch"} & set(methods):
                    policies[node.name] = path
                if build and [a.arg for a in build.args.args] == ["self", "control_hz"]:
                    recipes[node.name] = path
                bases[node.name] = (path, {b.id for b in node.bases if isinstance(b, ast.Name)})
    while extra := {n: p for n, (p, b) in bases.items() if n not in policies and b & set(policies)}:
        policies.update(extra)
    return policies, recipes


def isinstance_types(call: ast.Call) -> set[str]:
    """The class names the second argument of an ``isinstance`` call names (a name, ``a.Name``, a tuple, a union)."""
    names, stack = set(), [call.args[1]] if len(call.args) == 2 else []
    while stack:
        node = stack.pop()
        if isinstance(node, ast.Name):
            names.add(node.id)
        elif isinstance(node, ast.Attribute):
            names.add(node.attr)
        elif isinstance(node, ast.Tuple):
            stack.extend(node.elts)
        elif isinstance(node, ast.BinOp):
            stack.extend((node.left, node.right))
    return names


def test_only_the_policy_package_asks_what_a_policy_is():
    """The engine drives any policy by the one interface (`uqdrive.policy.interface.Policy`) and builds any recipe:
    outside `policy/` no ``isinstance`` names a policy or recipe class, and every recipe lives in `policy/` (so no
    switch on what a recipe is, such as a user spec's ``kind``, can sit elsewhere)."""
    trees = modules()
    policies, recipes = policy_and_recipe_classes(trees)
    assert {"Controller", "WarningController", "ConstantPolicy"} <= set(policies) and "ControllerSpec" in recipes
    outside = [path for path in trees if path.relative_to(PACKAGE).parts[0] != "policy"]
    asks = [
        f"{path.relative_to(PACKAGE)}:{node.lineno} isinstance on {sorted(isinstance_types(node) & named)}"
        for named in [set(policies) | set(recipes)]
        for path in outside
        for node in ast.walk(trees[path])
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "isinstance"
        if isinstance_types(node) & named
    ]
    elsewhere = [f"{name} ({path.relative_to(PACKAGE)})" for name, path in recipes.items() if path in outside]
    assert not asks, "\n".join(asks)
    assert not elsewhere, "recipes outside policy/: " + ", ".join(elsewhere)
