"""The project files a script runs: its import closure over `src/uqdrive` and `stages/`.

DVC reruns a stage only when one of its listed deps changes, and a cell is reused only while its
code digest matches, so both must cover every project file the code imports — transitively,
including imports inside functions (the stages import their pipeline lazily). This module finds
them by reading the source (`ast`), not by running it; third-party imports are ignored. Hydra
`_target_`s in the configs are imports too: pass them as ``modules``.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib
import site
import sysconfig
from collections.abc import Iterable
from pathlib import Path

import yaml

SRC = Path(__file__).resolve().parents[1]  # the folder holding the uqdrive package (src/ in a checkout)
PACKAGE = "uqdrive"


def module_file(name: str, src: Path) -> Path | None:
    """The file of module ``name`` under ``src`` (a module or a package's __init__), if it is the project's."""
    base = src.joinpath(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def _module_name(path: Path, src: Path) -> str | None:
    """Dotted name of a file under ``src`` (None for a script elsewhere, e.g. stages/)."""
    try:
        parts = list(path.relative_to(src).with_suffix("").parts)
    except ValueError:
        return None
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported_names(path: Path, src: Path) -> frozenset[str]:
    """Every module name a file imports anywhere in it, with relative imports made absolute; for
    ``from a import b`` both ``a`` and ``a.b`` (``b`` may be a submodule). Parsed once per version of the file:
    a stage asks for the same closure once per cell."""
    stat = path.stat()
    return _parsed_imports(path, src, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=4096)
def _parsed_imports(path: Path, src: Path, mtime_ns: int, size: int) -> frozenset[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    here = _module_name(path, src)
    package = here if path.name == "__init__.py" else (here.rpartition(".")[0] if here else "")
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1] if package else []
                base = ".".join([*anchor, *([node.module] if node.module else [])])
            else:
                base = node.module or ""
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names if alias.name != "*")
    return frozenset(n for n in names if n == PACKAGE or n.startswith(f"{PACKAGE}."))


def _with_parents(name: str) -> list[str]:
    """Importing a.b.c runs a/__init__, a/b/__init__ and a/b/c."""
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts) + 1)]


def import_closure(script: str | Path, modules: Iterable[str] = (), src: Path = SRC) -> set[Path]:
    """Project files (absolute) that running ``script`` imports, transitively, the script included;
    ``modules``: module names imported by other means (Hydra `_target_`s)."""
    seen: set[Path] = set()
    todo = [Path(script).resolve()]
    todo.extend(p for m in modules for n in _with_parents(m) if (p := module_file(n, src)) is not None)
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        for name in imported_names(path, src):
            todo.extend(p for n in _with_parents(name) if (p := module_file(n, src)) is not None)
    return seen


def config_targets(conf: Path) -> set[str]:
    """Modules named by ``_target_`` anywhere in the configs (Hydra imports them, e.g. callbacks)."""
    targets: set[str] = set()

    def walk(node: object) -> None:
        if isinstance(node, dict):
            target = node.get("_target_")
            if isinstance(target, str) and target.startswith(f"{PACKAGE}."):
                targets.add(target.rpartition(".")[0])
            for value in node.values():
                walk(value)
        elif isinstance(node, list):
            for value in node:
                walk(value)

    for path in sorted(conf.rglob("*.yaml")):
        walk(yaml.safe_load(path.read_text()))
    return targets


def stage_closure(script: Path, conf: Path, src: Path = SRC) -> set[Path]:
    """What a stage script runs: its import closure plus the modules its configs name."""
    return import_closure(script, config_targets(conf), src)


def file_digest(path: str | Path) -> str:
    """sha256 of a file's bytes: a retrained model is a new cell even at the same path."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def files_digest(paths: Iterable[Path], base: Path) -> str:
    """sha256 over the paths (relative to ``base``) and bytes of files: changes exactly when one of them does."""
    digest = hashlib.sha256()
    for path in sorted(paths):
        digest.update(path.relative_to(base).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def source_digest(module: str) -> str:
    """sha256 of the Python files of the top-level package ``module`` is in (that module alone if it is none):
    the code of a user's policy, hooks or env, for a cell's identity (editing any file of it makes a new cell)."""
    top = importlib.import_module(module.partition(".")[0])
    if not getattr(top, "__path__", None):
        if not getattr(top, "__file__", None):
            raise ValueError(f"module {top.__name__} has no source file")
        path = Path(top.__file__).resolve()
        return files_digest([path], path.parent)
    roots = [Path(p).resolve() for p in top.__path__]
    return files_digest([p.resolve() for root in roots for p in root.rglob("*.py")], roots[0].parent)


def user_sources(modules: Iterable[str]) -> dict[str, str]:
    """`source_digest` of each top-level package among ``modules`` that is the user's: neither uqdrive's (its
    files are in a cell's code digest) nor installed (site-packages, the standard library: a cell records an
    installed distribution's version instead)."""
    tops = sorted({m.partition(".")[0] for m in modules if m} - {PACKAGE})
    return {top: source_digest(top) for top in tops if not _installed(top)}


def _installed(top: str) -> bool:
    """Whether package (or module) ``top`` lies where installed code does (or has no file: built in)."""
    module = importlib.import_module(top)
    files = [module.__file__] if getattr(module, "__file__", None) else list(getattr(module, "__path__", []))
    paths = sysconfig.get_paths()
    roots = {paths[k] for k in ("stdlib", "platstdlib", "purelib", "platlib")}
    roots |= {*site.getsitepackages(), site.getusersitepackages()}
    resolved = [Path(root).resolve() for root in roots]
    return all(any(Path(f).resolve().is_relative_to(root) for root in resolved) for f in files)
