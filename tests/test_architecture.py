"""The shape docs/architecture.md describes: each package imports only the packages below it, no module name and no
class or type-alias name is defined twice, no function runs past 60 lines, and `pipeline/` holds stage functions
only."""

import ast
import builtins
import collections
import collections.abc
import itertools
import typing
from pathlib import Path

from uqdrive.sim.config import SCENARIO_KINDS

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
    "acquire": {"safety"} | BELOW_SAFETY,
    "analysis": {"acquire", "avoid", "envelope", "safety"} | BELOW_SAFETY,
    "report": {"acquire", "analysis", "avoid", "envelope", "replay", "safety"} | BELOW_SAFETY,
}
WING_PARTS = {"plan", "cells", "figure"}  # a wing's standard parts share names: envelope/plan.py, avoid/plan.py
TOOLS = {"bench", "tools"}  # commands and benchmarks: use any part; nothing imports them
ROOT_MAY_IMPORT: set[str] = (
    set()
)  # the root is plumbing: it imports no wing (an experiment is data's, a model stage models')
ROOT_PLUMBING = {  # the root's modules: what every stage shares to validate, run, record and track
    "__init__.py",
    "deps.py",  # a stage's code closure and the digests of a cell's files
    "figures.py",
    "files.py",
    "network_input.py",  # the frame the network takes: sim renders it, data and policy preprocess to it (siblings)
    "parallel.py",
    "records.py",
    "resolvers.py",
    "schema.py",
    "stage.py",
    "stage_schemas.py",
    "runs_view.py",  # the MLflow view every experiment opens with (tracking sets it)
    "tracking.py",
}
TYPE_FACTORIES = {"TypeVar", "NewType", "ParamSpec", "TypeVarTuple"}
TYPE_STATEMENT = getattr(ast, "TypeAlias", ())  # `type X = ...` (Python ≥ 3.12; the 3.11 parser has none)
GENERICS = (
    set(typing.__all__)
    | set(collections.abc.__all__)
    | {n for n in dir(builtins) if isinstance(getattr(builtins, n), type)}
)


def modules() -> dict[Path, ast.Module]:
    return {p: ast.parse(p.read_text()) for p in sorted(PACKAGE.rglob("*.py"))}


def imported_packages(tree: ast.Module, path: Path = PACKAGE / "__init__.py") -> set[str]:
    """The project's subpackages and root modules a module at ``path`` imports, in every spelling: ``import
    uqdrive.x``, ``from uqdrive.x import y``, ``from uqdrive import x`` and relative imports (``from . import x``,
    ``from ..x import y``)."""
    here = path.relative_to(PACKAGE).with_suffix("").parts
    package = here if path.name == "__init__.py" else here[:-1]
    package = package[:-1] if package and package[-1] == "__init__" else package
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[1] for a in node.names if a.name.startswith("uqdrive.")}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = package[: len(package) - node.level + 1]
                dotted = [*anchor, *(node.module.split(".") if node.module else [])]
            elif node.module == "uqdrive" or (node.module or "").startswith("uqdrive."):
                dotted = node.module.split(".")[1:]
            else:
                continue
            names |= {dotted[0]} if dotted else {a.name for a in node.names}
    return names


PACKAGES = {p.name for p in PACKAGE.iterdir() if p.is_dir() and any(p.glob("*.py"))}  # namespace ones too


def upward_imports(trees: dict[Path, ast.Module]) -> list[str]:
    """Every import of a package a module may not import: a layer's above its `LAYERS` entry, a root module's
    beyond `ROOT_MAY_IMPORT` (the root sits below every wing)."""
    upward = []
    for path, tree in trees.items():
        here = path.relative_to(PACKAGE).parts[0]
        if here in LAYERS:
            allowed = LAYERS[here] | {here}
        elif path.parent == PACKAGE:
            allowed = ROOT_MAY_IMPORT
        else:
            continue
        upward += [
            f"{path.relative_to(PACKAGE)} imports uqdrive.{n}"
            for n in imported_packages(tree, path) & PACKAGES - allowed
        ]
    return sorted(upward)


def test_packages_import_only_the_packages_below_them():
    upward = upward_imports(modules())
    assert not upward, "\n".join(upward)
    planted = {
        ("paper.py", "from uqdrive.analysis.method_answers import x"): True,  # the root below every wing
        ("stage.py", "from uqdrive import report"): True,
        ("stage.py", "from uqdrive.safety.plan import SafetyStage"): True,
        (
            "stage_schemas.py",
            "from uqdrive.data.binning import SteeringBins",
        ): True,  # not even data: an experiment is data's own
        ("sim/x.py", "from uqdrive.data import tables"): True,
        ("analysis/x.py", "from ..avoid import results"): False,
        ("safety/x.py", "from uqdrive.analysis import paper"): True,
    }
    for (where, code), caught in planted.items():
        assert bool(upward_imports({PACKAGE / where: ast.parse(code)})) == caught, (where, code)


def test_the_root_holds_only_plumbing():
    """What the root may hold (`ROOT_PLUMBING`): a domain module (the paper's numbers, say) lives in its wing."""
    root = {p.name for p in PACKAGE.glob("*.py")}
    assert root <= ROOT_PLUMBING, sorted(root - ROOT_PLUMBING)


def test_imports_are_found_in_every_spelling():
    source = (
        "import uqdrive.sim.world\nfrom uqdrive.models import x\nfrom uqdrive import safety, report as r\n"
        "from . import gym_env\nfrom ...uq.bounds import b\nfrom ... import data\nimport numpy\nfrom os import path\n"
    )
    found = imported_packages(ast.parse(source), PACKAGE / "sim" / "deep" / "mod.py")
    assert found == {"sim", "models", "safety", "report", "uq", "data"}
    assert imported_packages(ast.parse("from . import gym_env\n"), PACKAGE / "sim" / "__init__.py") == {"sim"}
    assert imported_packages(ast.parse("from . import records\n"), PACKAGE / "stage.py") == {"records"}


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


def pipeline_definitions(trees: dict[Path, ast.Module]) -> list[str]:
    """Every class and module-level type alias defined in `pipeline/`: a stage's schema, its plan and what its run
    returns live in the stage's wing (`safety/plan.py`, `models/train_plan.py`, `analysis/plans.py`, …), so
    `pipeline/` holds the stage functions only."""
    classes = {node.name for tree in trees.values() for node in ast.walk(tree) if isinstance(node, ast.ClassDef)}
    return [
        f"{path.relative_to(PACKAGE)}: {name}"
        for path, tree in trees.items()
        if path.relative_to(PACKAGE).parts[0] == "pipeline"
        for name in [n.name for n in ast.walk(tree) if isinstance(n, ast.ClassDef)] + type_aliases(tree, classes)
    ]


def test_pipeline_defines_no_schema_plan_or_record():
    defined = pipeline_definitions(modules())
    assert not defined, "\n".join(defined)
    planted = {
        "@schema(root=True)\nclass XStage(Stage):\n    x: int": True,
        "@dataclasses.dataclass(frozen=True)\nclass XRun:\n    reused: bool": True,
        'Name = Annotated[Str, Field(pattern="a")]': True,
        "def run_x(cfg):\n    return plan(cfg)": False,
        "LIMIT = 3": False,
    }
    for code, caught in planted.items():
        for folder, stage in (("pipeline", True), ("safety", False)):
            found = pipeline_definitions({PACKAGE / folder / "x_stage.py": ast.parse(code)})
            assert bool(found) == (caught and stage), (folder, code, found)


WHOLE_CONFIG = {"DictConfig", "AvoidStage", "AvoidSettings"}  # the avoid stage's config: composed, validated, built


class CallGraph:
    """Every function and class under src/uqdrive by module, what each module's names refer to, and the types that
    carry the config whole: `WHOLE_CONFIG` and every class with a field of such a type."""

    def __init__(self) -> None:
        self.defs, self.imports, self.paths, self.homes = {}, {}, {}, {}
        for path, tree in modules().items():
            parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            self.paths[name] = path
            self.defs[name] = {n.name: n for n in tree.body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
            self.homes |= {n.name: name for n in self.defs[name].values() if isinstance(n, ast.ClassDef)}
            package = name if parts[-1] == "__init__" else name.rsplit(".", 1)[0]
            self.imports[name] = {
                a.asname or a.name: (f"{package}.{node.module}" if node.level else node.module, a.name)
                for node in tree.body
                if isinstance(node, ast.ImportFrom) and node.module and (node.level or node.module.startswith("uq"))
                for a in node.names
            }
        self.config_types = set(WHOLE_CONFIG)
        while grown := {name for name in self.homes if self._holds_config(name)} - self.config_types:
            self.config_types |= grown

    def _holds_config(self, type_name: str) -> bool:
        cls = self.defs[self.homes[type_name]][type_name]
        fields = [n.annotation for n in cls.body if isinstance(n, ast.AnnAssign)]
        return any(n.id in self.config_types for f in fields for n in ast.walk(f) if isinstance(n, ast.Name))

    def resolve(self, module: str, name: str) -> tuple[str, ast.AST] | None:
        """The definition ``name`` means in ``module``, through imports and package re-exports."""
        for _ in range(5):
            if name in self.defs.get(module, {}):
                return module, self.defs[module][name]
            if name not in self.imports.get(module, {}):
                return None
            module, name = self.imports[module][name]
        return None

    def member(self, module: str, cls: ast.ClassDef, name: str) -> tuple[str, ast.AST] | None:
        """A class's method or field annotation, its bases searched too."""
        for node in cls.body:
            if isinstance(node, ast.FunctionDef) and node.name == name:
                return module, node
            if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.target.id == name:
                return module, node
        for base in cls.bases:
            found = isinstance(base, ast.Name) and self.resolve(module, base.id)
            if found and isinstance(found[1], ast.ClassDef) and (hit := self.member(*found, name)):
                return hit
        return None

    def member_of(self, type_name: str, name: str) -> tuple[str, ast.AST] | None:
        module = self.homes.get(type_name)
        cls = module and self.defs[module].get(type_name)
        return isinstance(cls, ast.ClassDef) and self.member(module, cls, name) or None

    def class_of(self, annotation: ast.AST | None) -> str | None:
        """The project class an annotation names: ``X``, ``mod.X``, ``"X"`` or ``X | None`` (not a container)."""
        if isinstance(annotation, ast.BinOp) and isinstance(annotation.op, ast.BitOr):
            return self.class_of(annotation.left) or self.class_of(annotation.right)
        name = annotation.attr if isinstance(annotation, ast.Attribute) else getattr(annotation, "id", None)
        if isinstance(annotation, ast.Constant) and isinstance(annotation.value, str):
            name = annotation.value
        return name if name in self.homes or name in self.config_types else None


def config_path(graph: CallGraph, start: tuple[str, str], param: str) -> tuple[set[str], int]:
    """The files the config enters from ``start``'s ``param`` and the calls that carry it there (see the test)."""
    files, calls, seen = set(), 0, set()
    todo = [(start[0], graph.defs[start[0]][start[1]], ((param, "DictConfig"),))]
    while todo:
        module, fn, bound = todo.pop()
        if (module, fn.name, bound) in seen:
            continue
        seen.add((module, fn.name, bound))
        files.add(str(graph.paths[module].relative_to(PACKAGE)))
        args = fn.args.posonlyargs + fn.args.args + fn.args.kwonlyargs
        types = {a.arg: t for a in args if (t := graph.class_of(a.annotation))} | dict(bound)

        def type_of(node: ast.AST, module=module, types=types) -> str | None:
            if isinstance(node, ast.Name):
                return types.get(node.id)
            if isinstance(node, ast.Attribute) and (owner := type_of(node.value)):
                hit = graph.member_of(owner, node.attr)
                return hit and graph.class_of(getattr(hit[1], "annotation", None) or getattr(hit[1], "returns", None))
            if isinstance(node, ast.Call) and (callee := _callee(graph, module, node, type_of)):
                named = [a.id for a in node.args if isinstance(a, ast.Name) and a.id in graph.config_types]
                return graph.class_of(getattr(callee[1], "returns", None)) or (named or [None])[0]  # validate(X, cfg)
            return None

        for _ in range(2):  # locals bound from a call or a field of a known class
            for node in ast.walk(fn):
                if isinstance(node, ast.Assign) and (t := type_of(node.value)):
                    types |= {target.id: t for target in node.targets if isinstance(target, ast.Name)}
                if isinstance(node, ast.withitem) and isinstance(node.optional_vars, ast.Name):
                    if t := type_of(node.context_expr):
                        types[node.optional_vars.id] = t
        for node in ast.walk(fn):
            if isinstance(node, ast.Call) and (entered := _entered(graph, module, node, type_of)):
                calls += 1
                todo.append(entered)
    return files, calls


def _entered(graph: CallGraph, module: str, call: ast.Call, type_of) -> tuple | None:
    """The function a call hands the config to, with its parameters that receive it, or None."""
    config = graph.config_types
    carried = [t if (t := type_of(a)) in config else None for a in call.args]
    carried += [t if (t := type_of(k.value)) in config else None for k in call.keywords]
    method = isinstance(call.func, ast.Attribute) and type_of(call.func.value)
    callee = _callee(graph, module, call, type_of)
    if not (any(carried) or method in config) or not callee or not isinstance(callee[1], ast.FunctionDef):
        return None
    params = [a.arg for a in callee[1].args.posonlyargs + callee[1].args.args]
    binding = {
        p: t for p, t in zip(params[1:] if method and _bound(callee[1]) else params, carried[: len(call.args)]) if t
    }
    binding |= {k.arg: t for k, t in zip(call.keywords, carried[len(call.args) :]) if t and k.arg}
    if method and params and method in config:
        binding[params[0]] = method
    return callee[0], callee[1], tuple(sorted(binding.items()))


def _bound(fn: ast.FunctionDef) -> bool:
    """A method that takes its instance or class first (not a staticmethod)."""
    return not any(ast.unparse(d) == "staticmethod" for d in fn.decorator_list)


def _callee(graph: CallGraph, module: str, call: ast.Call, type_of) -> tuple[str, ast.AST] | None:
    if isinstance(call.func, ast.Name):
        return graph.resolve(module, call.func.id)
    if isinstance(call.func, ast.Attribute) and (owner := type_of(call.func.value)):
        return graph.member_of(owner, call.func.attr)
    return None


def test_the_avoid_stages_config_enters_at_most_12_files_on_its_way_to_the_maths():
    """How the count is made (statically, with `ast`): start at `pipeline/avoid_stage.run_avoid(cfg)` and follow
    every call that hands on the stage's config whole, i.e. passes, or calls a method of, a value of a config type:
    the composed config, the validated stage, the settings built from it (`WHOLE_CONFIG`), or any class holding one
    of them in a field (the run driven from the settings). A value's type is its parameter's annotation, what the
    caller passed, a field's or property's annotation, or a callee's return annotation. Callees resolve through the
    module's imports (package re-exports too) and the classes' bases; calls into other libraries end the walk, and
    so do the config's sections (a `@schema` section handed on is a piece, not the config). The count is the files
    under src/uqdrive that hold a function so entered (its own module included). Before the avoid run was computed
    once (`AvoidRun`): 7 files, 40 calls; after: 7 files, 34 calls (the geometries and names built once, the
    answers reading the run; the trained model and a user's policy each a driver of the plan)."""
    files, calls = config_path(CallGraph(), ("uqdrive.pipeline.avoid_stage", "run_avoid"), "cfg")
    assert len(files) <= 12, f"{len(files)} files, {calls} calls: {sorted(files)}"


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


WORLD_TYPES = {  # the worlds (`uqdrive.sim.world.World`), their locations' configs and their lanes, the bodies, where
    # a rollout drives (a condition, a mixture of them) and the location types, one per world (`uqdrive.sim.location`)
    "World",
    "DrivingEnv",
    "GymWorld",
    "ScenarioConfig",
    "GymWorldConfig",
    "ScenarioGeometry",
    "DrivenPath",
    "Scene",
    "Condition",
    "Mixture",
    "Location",
    "RoadLocation",
    "GymLocation",
}


def world_questions(trees: dict[Path, ast.Module]) -> list[str]:
    """Every place outside `sim/` that asks which world it has: an ``isinstance``/``issubclass`` on a world type, a
    ``gym_world is None`` / ``is not None`` check, or a switch on a scenario kind's name (`SCENARIO_KINDS`:
    ``x.kind == "obstacle"``, ``kind != "roundabout"``, ``in (...)``)."""

    def asks(node: ast.AST) -> bool:
        if isinstance(node, ast.Call):
            return (
                isinstance(node.func, ast.Name)
                and node.func.id in ("isinstance", "issubclass")
                and len(node.args) == 2
                and bool({n for part in ast.walk(node.args[1]) for n in _names(part)} & WORLD_TYPES)
            )
        if not isinstance(node, ast.Compare):
            return False
        left, op, right = node.left, node.ops[0], node.comparators[0]
        if isinstance(op, ast.Is | ast.IsNot):
            named = getattr(left, "attr", getattr(left, "id", None))
            return named == "gym_world" and isinstance(right, ast.Constant) and right.value is None
        if isinstance(op, ast.Eq | ast.NotEq | ast.In | ast.NotIn):
            strings = [right, *getattr(right, "elts", [])]
            kind = getattr(left, "attr", getattr(left, "id", None)) == "kind"
            return kind and any(isinstance(v, ast.Constant) and v.value in SCENARIO_KINDS for v in strings)
        return False

    return [
        f"{path.relative_to(PACKAGE)}:{node.lineno} {ast.unparse(node)}"
        for path, tree in trees.items()
        if path.relative_to(PACKAGE).parts[0] != "sim"
        for node in ast.walk(tree)
        if asks(node)
    ]


def test_no_code_outside_sim_asks_which_world_it_has():
    asked = world_questions(modules())
    assert not asked, "\n".join(asked)


def test_world_questions_are_found():
    planted = {
        "isinstance(where, Condition)": True,
        "isinstance(where, Mixture | Condition)": True,
        "issubclass(kind, sim.location.GymLocation)": True,
        "stage.gym_world is None": True,
        "self.gym_world is not None and half_width": True,
        "gym_world is None": True,
        'scenario.kind == "obstacle"': True,
        "cfg.kind != 'roundabout'": True,
        'geometry.config.kind in ("obstacle", "straight")': True,
        'kind == "roundabout"': True,  # the kind read into a name first
        "stage.gym_world.env_id": False,
        "where.single is None": False,
        "policy.kind == kind": False,  # no string: not a switch on a kind's name
        "kind == 'gray'": False,  # a frame's kind, not a scenario's
        "isinstance(spec, ControllerSpec)": False,  # a policy type: the policy rule's
    }
    for code, caught in planted.items():
        for folder, outside in (("safety", True), ("sim", False)):
            found = world_questions({PACKAGE / folder / "planted.py": ast.parse(code)})
            assert bool(found) == (caught and outside), (folder, code, found)


DRIVING = {"pipeline", "avoid", "envelope"}  # the stages that drive, and the wings whose plans they call


def driver_questions(trees: dict[Path, ast.Module]) -> list[str]:
    """Every ``….policy is None`` / ``is not None`` in a driving stage or wing: what drives is resolved once
    (`uqdrive.safety.drive.resolve_driver`), never branched on."""
    return [
        f"{path.relative_to(PACKAGE)}:{node.lineno} {ast.unparse(node)}"
        for path, tree in trees.items()
        if path.relative_to(PACKAGE).parts[0] in DRIVING
        for node in ast.walk(tree)
        if isinstance(node, ast.Compare)
        and isinstance(node.ops[0], ast.Is | ast.IsNot)
        and isinstance(node.left, ast.Attribute)
        and node.left.attr == "policy"
        and isinstance(node.comparators[0], ast.Constant)
        and node.comparators[0].value is None
    ]


def test_no_stage_asks_which_driver_it_has():
    asked = driver_questions(modules())
    assert not asked, "\n".join(asked)
    planted = {"s.policy is not None": True, "stage.safety.policy is None": True, "policy is None": False}
    for code, caught in planted.items():
        for folder, driving in (("pipeline", True), ("safety", False)):
            found = driver_questions({PACKAGE / folder / "planted.py": ast.parse(code)})
            assert bool(found) == (caught and driving), (folder, code, found)


SCHEME_HOMES = {"uq/schemes.py", "policy/draws.py"}  # where a scheme's name becomes its object (a dict, no switch)


def _named_scheme(node: ast.expr) -> bool:
    name = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else ""
    return name == "scheme" or name.endswith("_scheme")


def _names_a_scheme(node: ast.expr) -> bool:
    """A string constant, or a tuple, list or set of them (``scheme in ("a", "b")``)."""
    if isinstance(node, ast.Tuple | ast.List | ast.Set):
        return bool(node.elts) and all(_names_a_scheme(e) for e in node.elts)
    return isinstance(node, ast.Constant) and isinstance(node.value, str)


def scheme_switches(trees: dict[Path, ast.Module]) -> list[str]:
    """Every switch on an estimator's or a draw scheme's name (``….scheme == "sequential"``, ``!=``, ``in (…)``,
    ``match scheme: case "fixed"``) outside `SCHEME_HOMES`: each scheme is an object behind one interface
    (`uqdrive.uq.schemes.CellEstimator`, `uqdrive.policy.draws.DrawScheme`), chosen once from its name."""
    found = []
    for path, tree in trees.items():
        if str(path.relative_to(PACKAGE)) in SCHEME_HOMES:
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Compare) and len(node.ops) == 1:
                sides = (node.left, node.comparators[0])
                if any(_named_scheme(a) and _names_a_scheme(b) for a, b in (sides, sides[::-1])):
                    found.append(f"{path.relative_to(PACKAGE)}:{node.lineno} {ast.unparse(node)}")
            elif isinstance(node, ast.Match) and _named_scheme(node.subject):
                found.append(f"{path.relative_to(PACKAGE)}:{node.lineno} match {ast.unparse(node.subject)}")
    return found


def test_no_code_switches_on_a_schemes_name():
    switched = scheme_switches(modules())
    assert not switched, "\n".join(switched)
    planted = {
        'if self.scheme == "sequential":\n    pass': True,
        'x = 1 if d.scheme != "fixed" else 2': True,
        'ok = "fixed" == settings.draws.scheme': True,
        'ok = scheme in ("chernoff", "clopper_pearson")': True,
        'ok = cell_scheme == "sequential"': True,
        'match scheme:\n    case "fixed":\n        pass': True,
        "ok = settings.scheme == other.scheme": False,
        'ok = method == "sequential"': False,
        "ok = DRAW_SCHEMES[settings.scheme]": False,
    }
    for code, caught in planted.items():
        for home, exempt in (("safety/planted.py", False), ("uq/schemes.py", True)):
            found = scheme_switches({PACKAGE / home: ast.parse(code)})
            assert bool(found) == (caught and not exempt), (home, code, found)


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


def is_record(node: ast.ClassDef) -> bool:
    """Decorated ``@record`` or ``@record(...)`` (`uqdrive.records.record`): a file's typed record."""
    return any(_names(d.func if isinstance(d, ast.Call) else d) & {"record"} for d in node.decorator_list)


RESULT_SUFFIXES = ("Result", "Record", "Cell", "Estimate", "Summary", "Run")  # a result type's name says so


def result_types(trees: dict[Path, ast.Module]) -> dict[str, ast.ClassDef]:
    """Every result type: a ``@record`` class, a dataclass named as a result (`RESULT_SUFFIXES`), and every
    class those hold in a field (transitively): what reaches a stage's file or a reader of one."""
    classes = {n.name: n for tree in trees.values() for n in ast.walk(tree) if isinstance(n, ast.ClassDef)}
    todo = [n for n in classes.values() if is_record(n) or (is_dataclass(n) and n.name.endswith(RESULT_SUFFIXES))]
    found: dict[str, ast.ClassDef] = {}
    while todo:
        node = todo.pop()
        if node.name not in found:
            found[node.name] = node
            held = {name for f in node.body if isinstance(f, ast.AnnAssign) for name in _names(f.annotation)}
            todo += [classes[name] for name in held if name in classes and is_dataclass(classes[name])]
    return found


def is_dataclass(node: ast.ClassDef) -> bool:
    return any(_names(d.func if isinstance(d, ast.Call) else d) & {"dataclass", "record"} for d in node.decorator_list)


def loose_fields(trees: dict[Path, ast.Module]) -> list[str]:
    """Result-type fields typed ``dict[…, Any]`` or a bare ``dict`` (a dict of anything) anywhere in the annotation."""

    def loose(part: ast.AST) -> bool:
        if isinstance(part, ast.Subscript) and _names(part.value) & {"dict", "Dict", "Mapping"}:
            return any(_names(n) & {"Any"} for n in ast.walk(part.slice))
        return isinstance(part, ast.Name) and part.id in {"dict", "Dict", "Mapping"}

    def bare(annotation: ast.expr) -> list[ast.AST]:  # the parts, a subscripted dict's own name left out
        subscripted = {id(n.value) for n in ast.walk(annotation) if isinstance(n, ast.Subscript)}
        return [n for n in ast.walk(annotation) if id(n) not in subscripted]

    return sorted(
        f"{node.name}.{field.target.id}: {ast.unparse(field.annotation)}"
        for node in result_types(trees).values()
        for field in node.body
        if isinstance(field, ast.AnnAssign) and isinstance(field.target, ast.Name)
        if any(loose(part) for part in bare(field.annotation))
    )


KEPT_LOOSE = {  # result-type fields that stay loose, each with why
    "Fitted.curve: list[dict]": "`Posterior.fit`'s return, the interface a user's posterior implements (README): "
    "a learning curve's rows hold the method's own columns beside step, train_loss, val_accuracy and val_nll",
    "Fitted.extra: dict[str, Any]": "the same interface: a method's own metrics (numbers, a diagnostics line), "
    "which `TrainMetrics` (an open record) writes beside its declared keys",
}


def test_no_result_field_is_typed_dict_of_any():
    """A result type (not only a ``@record``: `RareResult` is a plain dataclass) says what its fields hold; a
    field that stays loose is in `KEPT_LOOSE` with why, and an entry there that no longer applies goes."""
    found = loose_fields(modules())
    assert not set(found) - set(KEPT_LOOSE), "\n".join(sorted(set(found) - set(KEPT_LOOSE)))
    assert set(KEPT_LOOSE) <= set(found), "no longer loose: " + str(set(KEPT_LOOSE) - set(found))


def test_loose_result_fields_are_found():
    source = """
@dataclasses.dataclass(frozen=True)
class Inner:
    extra: dict[str, Any]

@dataclasses.dataclass(frozen=True)
class RareResult:
    inner: Inner
    records: list[dict]
    domain: dict[str, list[float]]

@dataclass
class Settings:
    options: dict[str, Any]

@record
class Kept:
    counts: Mapping[str, typing.Any] | None
"""
    assert loose_fields({Path("m.py"): ast.parse(source)}) == [
        "Inner.extra: dict[str, Any]",
        "Kept.counts: Mapping[str, typing.Any] | None",
        "RareResult.records: list[dict]",
    ]


def test_safety_keeps_the_closed_loop_engine_only():
    """`safety/` is the engine (rollouts, cells, runner, safe sets, records of a cell); policies, collision
    avoidance and failure replay live in their own wings. Its size says whether they crept back."""
    lines = sum(len(p.read_text().splitlines()) for p in (PACKAGE / "safety").glob("*.py"))
    assert lines <= 2_500, lines


# a class repeats another when it shares this many field names, this share of the smaller's
TWIN_FIELDS, TWIN_SHARE = 5, 0.6
_PER_FRAME = "the per-frame measures of a decision's draws (η2, its counts, mutual information and its standard error, "
KEPT_TWINS = {  # pairs that share that much and stay, each with why
    frozenset({"MethodAnswer", "ReplicateInterval"}): "a method's answer copies the interval's value, low, high and "
    "gamma, but its own `method` (mcd, vi) and `replicates` (their seeds) are other things under the same names, "
    "and metrics/safety.json holds both sets of keys flat, so an embedded flattened interval would collide",
    frozenset({"SafetyGrid", "Sweep"}): "a grid stage's `sweep:` section, whose lists may be empty (heldout's names "
    "weathers and noises only), against the same five lists at the root of the findings, report and safety-summary "
    "configs, none empty: one embedding the other would move the keys users override (`methods=[mcd]` against "
    "`sweep.methods=[mcd]`) or let those stages accept an empty grid",
    frozenset({"CertifyRecord", "CertifySection"}): "the certify record echoes six of its section's 31 settings "
    "(policy, η, θ, γ, budget, base seed) so that its file says what it answers for; embedding the section would "
    "write every setting into metrics/certify.json",
    frozenset({"ClaimResult", "Finding"}): "two decided tests under one vocabulary (name, interval, level, α, "
    "p-value, verdict, reason, replicates, estimand): a method-level claim on the mean and q against a paired "
    "comparison with its discordant runs. A decided-test type both embed (flattened, so the files keep their keys) "
    "is the fix; it is not made yet: both are built by the claims and findings code and read by the report",
    frozenset({"ClaimResult", "MeanInterval"}): "a betting interval vectorised over many simulated runs (arrays) "
    "against one claim's scalar answer, which reads one element of it",
    frozenset({"Command", "FrameDecision"}): _PER_FRAME + "entropy): a policy's decision for one frame and the "
    "command it returns carry the same numbers at the interface",
    frozenset({"FrameDecision", "FrameMeasures"}): _PER_FRAME + "entropy) of one frame, then with its decision",
    frozenset({"Command", "RolloutResult"}): _PER_FRAME + "warning): one frame's floats against a rollout's "
    "per-step arrays of them",
    frozenset({"FrameDecision", "RolloutResult"}): _PER_FRAME + "draws): one frame's floats against a rollout's "
    "per-step arrays of them",
    frozenset({"PolicyConfig", "UserPolicySpec"}): "a policy YAML's schema (what a user writes) and the picklable "
    "recipe a job carries, built from it with the stage's own speed, eps and draws where the YAML names none",
    frozenset({"RuleRecord", "WarningConfig"}): "the deployed warning rule as avoid's file writes it (each level's "
    "action as an `ActionRecord` by name, the draws and tier rule beside) against the `warning:` config it came "
    "from (actions as `WarningLevels`): the same names, other types",
}


def dataclass_fields(trees: dict[Path, ast.Module]) -> dict[str, dict[str, str]]:
    """Each dataclass-like class (``@dataclass``, ``@record``, ``@schema``) → its own fields' annotations, by name."""
    found = {}
    for tree in trees.values():
        for node in (n for n in ast.walk(tree) if isinstance(n, ast.ClassDef)):
            decorators = {n for d in node.decorator_list for n in _names(d.func if isinstance(d, ast.Call) else d)}
            if decorators & {"dataclass", "record", "schema"}:
                found[node.name] = {
                    f.target.id: ast.unparse(f.annotation)
                    for f in node.body
                    if isinstance(f, ast.AnnAssign) and isinstance(f.target, ast.Name)
                    if "ClassVar" not in ast.unparse(f.annotation)
                }
    return found


def twins(classes: dict[str, dict[str, str]]) -> dict[frozenset, list[str]]:
    """The pairs of classes that share at least `TWIN_FIELDS` field names (whatever their annotations: a float and
    a `float | None` are the same idea) making up at least `TWIN_SHARE` of the smaller's fields, with those names."""
    found = {}
    for (a, fa), (b, fb) in itertools.combinations(classes.items(), 2):
        shared = sorted(fa.keys() & fb.keys())
        if len(shared) >= TWIN_FIELDS and len(shared) >= TWIN_SHARE * min(len(fa), len(fb)):
            found[frozenset({a, b})] = shared
    return found


def test_twins_are_found():
    source = """
@dataclass(frozen=True)
class Result:
    name: str
    low: float
    high: float
    p_value: float
    level: float
    verdict: str

@record
class Repeats:
    family: str
    name: str
    low: float
    high: float
    p_value: float
    level: float

@record
class Embeds:
    family: str
    result: Result = flattened()

@record
class Retyped:  # the same names, other annotations: 5 of its 8 fields (62 %), a twin
    name: str | None
    low: float | None
    high: float | None
    p_value: list[float]
    level: int
    a: int
    b: int
    c: int

@record
class Apart:  # shares 5 of its 9 fields (56 %) with Aside's 9: no twins
    u: int
    v: int
    w: int
    x: int
    y: int
    d: int
    e: int
    f: int
    g: int

@record
class Aside:
    u: int
    v: int
    w: int
    x: int
    y: int
    h: int
    i: int
    j: int
    k: int
"""
    found = twins(dataclass_fields({Path("m.py"): ast.parse(source)}))
    shared = ["high", "level", "low", "name", "p_value"]
    assert found == {
        frozenset(pair): shared for pair in [("Result", "Repeats"), ("Result", "Retyped"), ("Repeats", "Retyped")]
    }


def test_no_record_repeats_another():
    """One record per idea: a record that carries a result computed elsewhere embeds it (a `flattened` field of
    `uqdrive.records` keeps the file's keys) rather than repeating its fields; a pair that stays is in `KEPT_TWINS`
    with why, and an entry there that no longer applies goes."""
    found = twins(dataclass_fields(modules()))
    repeated = [f"{' ~ '.join(sorted(pair))}: {fields}" for pair, fields in found.items() if pair not in KEPT_TWINS]
    assert not repeated, "\n".join(repeated)
    assert set(KEPT_TWINS) <= set(found), "no longer twins: " + str(set(KEPT_TWINS) - set(found))
