"""The issue's measurable rules over the package's source, read with ``ast``: layers, cycles,
private names, settings keys and function length (complexity is ruff's ``C90``, see
pyproject.toml)."""

from __future__ import annotations

import ast
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("common", "estimator", "frontend", "datasets", "app", "cli")
"""The layers from the bottom up: each may import only its own and those before it."""
MAX_LINES = 79
"""Longest function allowed, docstring and decorators' lines excluded, body included."""
SETTINGS_SECTIONS = frozenset({"camera", "noise", "odometry", "overlay", "rig", "topics"})
"""First parts of the dotted settings keys (``"camera.delay_ms"``)."""
SETTINGS_HOME = "markergraph.settings"
"""The one module that reads settings by key."""


@dataclass(frozen=True, slots=True)
class Module:
    """One module of the package."""

    name: str
    """Its import name (``markergraph.estimator.slam``); a package's ``__init__`` has the
    package's name."""
    path: Path
    """Its file."""
    layer: str
    """The folder layer it belongs to, one of :data:`LAYERS`."""
    tree: ast.Module
    """Its parsed source."""

    @property
    def is_package(self) -> bool:
        """Whether it is a package's ``__init__``."""
        return self.path.name == "__init__.py"

    @property
    def package(self) -> str:
        """The package it lives in (itself for an ``__init__``)."""
        return self.name if self.is_package else self.name.rpartition(".")[0]

    def where(self, node: ast.AST) -> str:
        """``file:line`` of a node, relative to the repository."""
        return f"{self.path.relative_to(ROOT)}:{getattr(node, 'lineno', 0)}"


@dataclass(frozen=True, slots=True)
class Imported:
    """One name an import statement brings in."""

    module: str
    """The module it resolves to (a package's name for a name its ``__init__`` holds)."""
    name: str | None
    """The name taken from it (``from m import name``), None for ``import m``."""
    node: ast.stmt
    """The import statement."""


def _package_dirs() -> dict[str, Path]:
    """pyproject.toml's package-dir: import name -> folder."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    package_dir = pyproject["tool"]["setuptools"]["package-dir"]
    return {name: ROOT / folder for name, folder in package_dir.items()}


def _layer_of(name: str) -> str:
    """The layer of an import name: its second part if that is a layer, else the app's."""
    parts = name.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else "app"


def _modules() -> dict[str, Module]:
    """Every module of the package by import name."""
    modules: dict[str, Module] = {}
    roots = _package_dirs()
    for package, folder in roots.items():
        for path in sorted(folder.rglob("*.py")):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if any(other != folder and other in path.parents for other in roots.values()):
                continue  # a folder nested under this one is its own package (none today)
            if parts[-1] == "__init__":
                parts.pop()
            name = ".".join([package, *parts])
            tree = ast.parse(path.read_text(), filename=str(path))
            modules[name] = Module(name, path, _layer_of(name), tree)
    return modules


MODULES = _modules()


def _imports(module: Module) -> Iterator[Imported]:
    """Every import of a module, those inside functions and ``TYPE_CHECKING`` blocks included.

    ``from package import name`` resolves to the submodule when ``name`` is one, else to the
    package (its ``__init__`` holds the name).
    """
    for node in ast.walk(module.tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield Imported(alias.name, None, node)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the module's own package upwards
                anchor = module.package.rsplit(".", node.level - 1)[0]
                base = f"{anchor}.{base}" if base else anchor
            for alias in node.names:
                submodule = f"{base}.{alias.name}"
                target = submodule if submodule in MODULES else base
                yield Imported(target, alias.name, node)


def _internal(imported: Imported) -> bool:
    return imported.module == "markergraph" or imported.module.startswith("markergraph.")


def _graph() -> dict[str, set[str]]:
    """Module -> the package modules it imports.

    Importing ``a.b.c`` runs ``a.b``'s ``__init__`` first, but that is not counted as an edge to
    it: every re-exporting ``__init__`` would then be in a cycle with its own submodules. Only an
    explicit ``from a.b import name`` (or ``import a.b``) is an edge to ``a.b``, so a submodule
    that takes a name from its own package's ``__init__`` is caught as the cycle it is, while
    ``__init__`` re-exporting its submodules is not.
    """
    graph: dict[str, set[str]] = {name: set() for name in MODULES}
    for module in MODULES.values():
        for imported in _imports(module):
            if imported.module in MODULES and imported.module != module.name:
                graph[module.name].add(imported.module)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(name: str) -> None:
        index[name] = low[name] = len(index)
        stack.append(name)
        on_stack.add(name)
        for other in sorted(graph[name]):
            if other not in index:
                visit(other)
                low[name] = min(low[name], low[other])
            elif other in on_stack:
                low[name] = min(low[name], index[other])
        if low[name] == index[name]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == name:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(graph)))
    for name in sorted(graph):
        if name not in index:
            visit(name)
    return found


def _report(offenders: list[str]) -> str:
    return f"{len(offenders)} offender(s):\n" + "\n".join(offenders)


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def test_no_module_imports_a_layer_above_its_own() -> None:
    """No module imports one from a layer above its own (common < estimator < ... < cli)."""
    offenders = [
        f"{module.where(imported.node)}: {module.layer} imports {imported.module} "
        f"({_layer_of(imported.module)})"
        for module in MODULES.values()
        for imported in _imports(module)
        if _internal(imported)
        and LAYERS.index(_layer_of(imported.module)) > LAYERS.index(module.layer)
    ]
    assert not offenders, _report(offenders)


def test_no_import_cycles() -> None:
    """No two modules import each other, directly or through others."""
    graph = _graph()
    offenders = []
    for cycle in _cycles(graph):
        members = set(cycle)
        for name in cycle:
            module = MODULES[name]
            for imported in _imports(module):
                if imported.module in members and imported.module != name:
                    offenders.append(f"{module.where(imported.node)}: {name} -> {imported.module}")
    assert not offenders, _report(sorted(set(offenders)))


def test_no_private_name_imported_across_modules() -> None:
    """No private name (``_x``) is imported from another module; a package may import its
    own private submodules, and a private module's own package may use it."""
    offenders = []
    for module in MODULES.values():
        for imported in _imports(module):
            if not _internal(imported):
                continue
            if imported.name is not None and _is_private(imported.name):
                own_submodule = imported.module == f"{module.package}.{imported.name}"
                if not own_submodule:
                    offenders.append(f"{module.where(imported.node)}: {imported.name}")
            private_parts = [p for p in imported.module.split(".") if _is_private(p)]
            home = imported.module.rpartition(".")[0]
            if private_parts and module.package != home:
                offenders.append(f"{module.where(imported.node)}: module {imported.module}")
    assert not offenders, _report(offenders)


def _settings_key(node: ast.expr) -> str | None:
    """A string constant that is a settings key (``"camera.delay_ms"``), else None."""
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        section, dot, _ = node.value.partition(".")
        if dot and section in SETTINGS_SECTIONS and re.fullmatch(r"[a-z_.]+", node.value):
            return node.value
    return None


def _names_values(node: ast.expr) -> bool:
    """Whether an expression is something named ``values`` (``values``, ``config.values``)."""
    return (isinstance(node, ast.Name) and node.id == "values") or (
        isinstance(node, ast.Attribute) and node.attr == "values"
    )


def _settings_reads(tree: ast.Module) -> Iterator[tuple[ast.AST, str]]:
    """Settings read by string key: ``x["camera.delay_ms"]``, ``x.get("camera.delay_ms")``, or
    any string subscript of something named ``values``."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Subscript):
            key = _settings_key(node.slice)
            constant = isinstance(node.slice, ast.Constant) and isinstance(node.slice.value, str)
            if key is not None or (constant and _names_values(node.value)):
                yield node, ast.unparse(node)
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "get"
            and node.args
        ):
            key = _settings_key(node.args[0])
            constant = isinstance(node.args[0], ast.Constant)
            if key is not None or (constant and _names_values(node.func.value)):
                yield node, ast.unparse(node)


def test_no_settings_read_by_string_key_outside_settings() -> None:
    """No module but ``app/settings.py`` reads a setting by its string key."""
    offenders = [
        f"{module.where(node)}: {text}"
        for module in MODULES.values()
        if module.name != SETTINGS_HOME
        for node, text in _settings_reads(module.tree)
    ]
    assert not offenders, _report(offenders)


def _python_files() -> Iterator[Path]:
    """The package's modules, the tests and the notebooks."""
    yield from (module.path for module in MODULES.values())
    for folder in ("tests", "notebooks"):
        yield from sorted((ROOT / folder).rglob("*.py"))


def test_every_function_is_under_80_lines() -> None:
    """Every function, tests and notebooks included, is under 80 lines (docstring included)."""
    offenders = []
    for path in _python_files():
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                lines = node.end_lineno - node.lineno + 1  # type: ignore[operator]
                if lines > MAX_LINES:
                    where = f"{path.relative_to(ROOT)}:{node.lineno}"
                    offenders.append(f"{where}: {node.name} has {lines} lines")
    assert not offenders, _report(offenders)


def test_readme_names_every_module() -> None:
    """docs/architecture.md names every module of the package, so a newcomer finds where a
    feature lives."""
    section = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    missing = [
        str(path.relative_to(ROOT))
        for folder in LAYERS
        for path in sorted((ROOT / folder).rglob("*.py"))
        if path.name not in ("__init__.py", "__main__.py") and path.name not in section
    ]
    assert not missing, _report(missing)
