"""The import structure of the project (docs/architecture.md), read from the source with ``ast``.

Rules:

* no import loop between the project's modules (every import counts, also one inside a function:
  a lazy import hides a loop, it does not remove it);
* layers airpuff_core < sweep < api: a module imports nothing from a layer above its own;
* the Numba kernels (``airpuff_core.kernels``) import nothing of the project outside ``kernels``;
* the browser pages (``api.pages``) reach jobs through the jobs layer (``api.jobs``), never through
  the JSON routes (``api.routes``);
* only the sweep engine (``sweep.engine``) submits point tasks: no other module imports
  ``sweep.worker`` (``sweep.cluster`` excepted: it warms the workers with the task itself);
* the cornea models live behind their registry: only ``airpuff_core.cornea`` imports the modules
  of the models (``membrane``, ``kirchhoff``, ``mindlin``), and no module outside it names a
  model's class (the rest of the project asks ``cornea.build.cornea_for_run`` by name).

A module's own ancestor packages are not counted as its imports: Python runs a package's
``__init__`` before any of its modules anyway, so ``from . import __version__`` adds no order.
"""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LAYERS = ("airpuff_core", "sweep", "api")  # lowest first
KERNELS = "airpuff_core.kernels"
CORNEA = "airpuff_core.cornea"


def project_modules(root: Path, packages=LAYERS) -> dict[str, Path]:
    """Dotted module name -> file, for every ``.py`` file of ``packages`` under ``root``."""
    modules = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = path
    return modules


def _imported_names(module: str, path: Path) -> set[str]:
    """Absolute dotted names imported by ``module`` (anywhere in the file), with ``from a import
    b`` giving both ``a`` and ``a.b`` (``a.b`` counts only if it is a module)."""
    is_package = path.name == "__init__.py"
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                if not is_package:
                    base = base[:-1]
                base = base[:len(base) - (node.level - 1)]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module
            names.add(prefix)
            names.update(f"{prefix}.{alias.name}" for alias in node.names)
    return names


def import_graph(root: Path, packages=LAYERS) -> dict[str, set[str]]:
    """Module -> the project modules it imports (its own ancestor packages left out)."""
    modules = project_modules(root, packages)
    graph = {}
    for module, path in modules.items():
        ancestors = {".".join(module.split(".")[:i]) for i in range(1, module.count(".") + 1)}
        if path.name == "__init__.py":
            ancestors.add(module)
        graph[module] = {name for name in _imported_names(module, path)
                         if name in modules and name not in ancestors and name != module}
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return cycles


def layer_violations(graph: dict[str, set[str]]) -> list[str]:
    """Imports from a lower layer into a higher one, and from the kernels out of ``kernels``."""
    def layer(module: str) -> int:
        return LAYERS.index(module.split(".")[0])

    problems = []
    for module, imported in sorted(graph.items()):
        for name in sorted(imported):
            if layer(name) > layer(module):
                problems.append(f"{module} imports {name}, a higher layer")
            in_kernels = module == KERNELS or module.startswith(KERNELS + ".")
            if in_kernels and not (name == KERNELS or name.startswith(KERNELS + ".")):
                problems.append(f"{module} (a kernel module) imports {name}")
    return problems


# (module, a module it must not import, why)
FORBIDDEN = (
    ("api.pages", "api.routes", "the pages use the jobs layer, api.jobs"),
)
# Modules that may import the task of a point; the runners go through sweep.engine.
WORKER_TASK = "sweep.worker"
WORKER_TASK_USERS = ("sweep.engine", "sweep.cluster")


def rule_violations(graph: dict[str, set[str]]) -> list[str]:
    """Imports that the rules above forbid (pages -> routes, submitting points besides the
    engine)."""
    problems = [f"{module} imports {name}: {why}" for module, name, why in FORBIDDEN
                if name in graph.get(module, set())]
    problems += [f"{module} imports {WORKER_TASK}: only the sweep engine submits points"
                 for module, imported in sorted(graph.items())
                 if WORKER_TASK in imported and module not in WORKER_TASK_USERS]
    return problems


def cornea_models(root: Path) -> dict[str, set[str]]:
    """The modules of the cornea models (those of ``cornea/`` that define a class with a ``name``
    attribute, as the registry's models do) -> the names of those classes."""
    models = {}
    for module, path in project_modules(root, (CORNEA.replace(".", "/"),)).items():
        classes = set()
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.ClassDef) and any(
                    isinstance(stmt, ast.Assign) and any(
                        isinstance(t, ast.Name) and t.id == "name" for t in stmt.targets)
                    for stmt in node.body):
                classes.add(node.name)
        if classes:
            models[module] = classes
    return models


def cornea_violations(root: Path, graph: dict[str, set[str]]) -> list[str]:
    """Imports of a cornea model's module, and names of a model's class, outside ``cornea``."""
    models = cornea_models(root)
    classes = set().union(*models.values()) if models else set()
    problems = []
    for module, path in sorted(project_modules(root).items()):
        if module == CORNEA or module.startswith(CORNEA + "."):
            continue
        for name in sorted(graph[module] & set(models)):
            problems.append(f"{module} imports {name}, a cornea model (use the registry)")
        named = {node.id for node in ast.walk(ast.parse(path.read_text()))
                 if isinstance(node, ast.Name)}
        named |= {alias.name for node in ast.walk(ast.parse(path.read_text()))
                  if isinstance(node, ast.ImportFrom) for alias in node.names}
        for cls in sorted(named & classes):
            problems.append(f"{module} names {cls}, a cornea model's class")
    return problems


def check(root: Path) -> list[str]:
    """Every problem of the import structure of the project under ``root``."""
    graph = import_graph(root)
    return ([f"import loop: {' <-> '.join(c)}" for c in import_cycles(graph)]
            + layer_violations(graph) + rule_violations(graph)
            + cornea_violations(root, graph))


# -- the project ---------------------------------------------------------------------------------

def test_the_project_has_no_import_loop_and_no_upward_import():
    graph = import_graph(REPO)
    assert len(graph) > 30 and "api.cli" in graph and "airpuff_core.kernels.mfpm" in graph
    assert check(REPO) == []


def test_the_cornea_models_are_the_registrys_and_only_cornea_knows_their_classes():
    from airpuff_core.cornea.build import MODELS
    from airpuff_core.cornea.registry import CORNEAS

    models = cornea_models(REPO)
    assert set(models) == {"airpuff_core.cornea.membrane", "airpuff_core.cornea.kirchhoff",
                           "airpuff_core.cornea.mindlin"}
    assert {cls.__name__ for cls in MODELS.values()} == set().union(*models.values())
    assert list(MODELS) == list(CORNEAS)
    assert cornea_violations(REPO, import_graph(REPO)) == []


def test_a_planted_upward_import_and_loop_in_a_copy_of_the_project_are_found(tmp_path):
    for package in LAYERS:
        shutil.copytree(REPO / package, tmp_path / package,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc"))
    assert check(tmp_path) == []
    with open(tmp_path / "sweep" / "grid.py", "a") as fh:  # sweep -> api: upward
        fh.write("\n\ndef _planted():\n    from api.cli import main\n    return main\n")
    with open(tmp_path / "sweep" / "storage.py", "a") as fh:  # storage <-> worker: a loop
        fh.write("\nfrom . import worker\n")
    with open(tmp_path / "api" / "pages.py", "a") as fh:  # pages -> routes
        fh.write("\n\ndef _planted():\n    from . import routes\n    return routes\n")
    with open(tmp_path / "api" / "runner.py", "a") as fh:  # a second submitter of points
        fh.write("\n\ndef _planted():\n    from sweep.worker import compute_point\n")
    with open(tmp_path / "airpuff_core" / "coupling.py", "a") as fh:  # a model past the registry
        fh.write("\n\ndef _planted():\n    from .cornea.mindlin import MindlinShell\n"
                 "    return MindlinShell\n")
    problems = check(tmp_path)
    assert "api.pages imports api.routes: the pages use the jobs layer, api.jobs" in problems
    assert "api.runner imports sweep.worker: only the sweep engine submits points" in problems
    assert "sweep.grid imports api.cli, a higher layer" in problems, problems
    assert any(p.startswith("import loop: ") and "sweep.storage" in p and "sweep.worker" in p
               for p in problems), problems
    assert ("airpuff_core.coupling imports airpuff_core.cornea.mindlin, a cornea model (use the "
            "registry)") in problems, problems
    assert "airpuff_core.coupling names MindlinShell, a cornea model's class" in problems, problems


# -- the checker itself, on a tiny synthetic project ---------------------------------------------

def _write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_the_checker_on_a_synthetic_project(tmp_path):
    _write(tmp_path, {
        "airpuff_core/__init__.py": "__version__ = '0'\n",
        "airpuff_core/params.py": "from . import __version__\n",  # its own package: not counted
        "airpuff_core/kernels/__init__.py": "",
        "airpuff_core/kernels/ok.py": "from .other import f\n",
        "airpuff_core/kernels/other.py": "import numpy\n\ndef f():\n    pass\n",
        "airpuff_core/kernels/bad.py": "from ..params import __version__\n",
        "sweep/__init__.py": "",
        "sweep/a.py": "import sweep.b\nfrom airpuff_core import params\n",
        "sweep/b.py": "def g():\n    from .a import x\n",  # a lazy import closes a loop
        "api/__init__.py": "",
        "api/x.py": "from sweep import a\n",
    })
    graph = import_graph(tmp_path)
    assert graph["airpuff_core.params"] == set()
    assert graph["sweep.a"] == {"sweep.b", "airpuff_core", "airpuff_core.params"}
    assert graph["api.x"] == {"sweep", "sweep.a"}
    assert import_cycles(graph) == [["sweep.a", "sweep.b"]]
    assert layer_violations(graph) == [
        "airpuff_core.kernels.bad (a kernel module) imports airpuff_core.params"]

    _write(tmp_path, {"airpuff_core/params.py": "def h():\n    import api.x\n"})
    assert "airpuff_core.params imports api.x, a higher layer" in check(tmp_path)
