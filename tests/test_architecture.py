"""The shape docs/architecture.md describes: each package imports only the packages below it, no module name and no
class or type-alias name is defined twice, no function runs past 60 lines, and `pipeline/` holds stage functions
only."""

import ast
import builtins
import collections
import collections.abc
import typing
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
TYPE_FACTORIES = {"TypeVar", "NewType", "ParamSpec", "TypeVarTuple"}
TYPE_STATEMENT = getattr(ast, "TypeAlias", ())  # `type X = ...` (Python ≥ 3.12; the 3.11 parser has none)
GENERICS = (
    set(typing.__all__)
    | set(collections.abc.__all__)
    | {n for n in dir(builtins) if isinstance(getattr(builtins, n), type)}
)


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


def _names(node: ast.expr) -> set[str]:
    """The identifier a name or dotted name ends in (``Literal``, ``typing.Literal`` → Literal)."""
    return {node.id} if isinstance(node, ast.Name) else {node.attr} if isinstance(node, ast.Attribute) else set()


def is_type_expression(value: ast.expr, classes: set[str]) -> bool:
    """Whether a module-level assignment's value is a type: a typing factory's call (``TypeVar(...)``,
    ``NewType(...)``), a generic subscripted (``Literal[...]``, ``tuple[...]``, ``Mapping[...]``), a ``|`` of
    types (a class, a typing or builtin type, ``None``), or a project class under another name."""
    if isinstance(value, ast.Call):
        return bool(_names(value.func) & TYPE_FACTORIES)
    if isinstance(value, ast.Subscript):
        return bool(_names(value.value) & GENERICS)
    if isinstance(value, ast.BinOp) and isinstance(value.op, ast.BitOr):
        sides = (value.left, value.right)
        return all(
            (isinstance(s, ast.Constant) and s.value is None)
            or bool(_names(s) & (classes | GENERICS))
            or is_type_expression(s, classes)
            for s in sides
        )
    return bool(_names(value) & classes)


def type_aliases(tree: ast.Module, classes: set[str]) -> list[str]:
    """The module-level type aliases a module defines: ``type X = ...``, ``X: TypeAlias = ...`` and ``X = <a
    type expression>`` (`is_type_expression`)."""
    found = []
    for node in tree.body:
        if isinstance(node, TYPE_STATEMENT):
            found.append(node.name.id)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            if "TypeAlias" in _names(node.annotation):
                found.append(node.target.id)
        elif isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            if is_type_expression(node.value, classes):
                found.append(node.targets[0].id)
    return found


def test_no_module_class_or_type_alias_name_is_defined_twice():
    trees = modules()
    names, types = collections.defaultdict(list), collections.defaultdict(list)
    classes = {node.name for tree in trees.values() for node in ast.walk(tree) if isinstance(node, ast.ClassDef)}
    for path, tree in trees.items():
        rel = path.relative_to(PACKAGE)
        if path.name != "__init__.py" and path.stem not in WING_PARTS:
            names[path.stem].append(str(rel))
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                types[node.name].append(f"{rel} (class)")
        for alias in type_aliases(tree, classes):
            types[alias].append(f"{rel} (alias)")
    names.update({p.name: [*names[p.name], f"{p.name}/"] for p in PACKAGE.iterdir() if p.is_dir()})
    assert not {k: v for k, v in names.items() if len(v) > 1}
    assert not {k: v for k, v in types.items() if len(v) > 1}


def test_type_aliases_are_found():
    source = """
import typing
from typing import Literal, TypeAlias, TypeVar
A = Literal["a", "b"]
B = int | None
C: TypeAlias = "dict[str, int]"
E = TypeVar("E")
F = typing.NewType("F", int)
G = Known
LIMIT = 3
TABLE = {"a": 1}
FIRST = TABLE["a"]
FLAGS = LIMIT | 4
"""
    assert type_aliases(ast.parse(source), {"Known"}) == ["A", "B", "C", "E", "F", "G"]


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


def is_record(node: ast.ClassDef) -> bool:
    """Decorated ``@record`` or ``@record(...)`` (`uqdrive.records.record`): a file's typed record."""
    return any(_names(d.func if isinstance(d, ast.Call) else d) & {"record"} for d in node.decorator_list)


def test_no_record_field_is_typed_dict_of_any():
    loose = [
        f"{path.relative_to(PACKAGE)}: {node.name}.{field.target.id}: {ast.unparse(field.annotation)}"
        for path, tree in modules().items()
        for node in ast.walk(tree)
        if isinstance(node, ast.ClassDef) and is_record(node)
        for field in node.body
        if isinstance(field, ast.AnnAssign) and isinstance(field.target, ast.Name)
        if any(
            isinstance(part, ast.Subscript)
            and _names(part.value) & {"dict", "Dict", "Mapping"}
            and any(_names(n) & {"Any"} for n in ast.walk(part.slice))
            for part in ast.walk(field.annotation)
        )
    ]
    assert not loose, "\n".join(loose)
