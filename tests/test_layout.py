"""The repository's layout (docs/architecture.md, "Outside the packages"): benchmarks, studies and
tools are packages run as ``python -m``, nothing edits ``sys.path`` to import, and every command of
the docs that runs one of the project's modules names a module that exists."""

from __future__ import annotations

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FOLDERS = ("airpuff_core", "sweep", "api", "benchmarks", "studies", "tools", "tests", "examples")
DOCS = [REPO / "README.md", REPO / "Makefile", *sorted((REPO / "docs").glob("*.md"))]
RUN_MODULE = re.compile(r"(?:python3?|\$\(PY\)) -m ((?:benchmarks|studies|tools|sweep|api)(?:\.[a-z_][a-z0-9_]*)+)")
RUN_SCRIPT = re.compile(r"(?:python3?|\$\(PY\)) ((?:benchmarks|studies|tools)/\w+\.py)")


def sources():
    for folder in FOLDERS:
        yield from sorted((REPO / folder).rglob("*.py"))


def edits_sys_path(tree: ast.AST) -> list[int]:
    """Lines that call a method of ``sys.path`` or assign to it."""
    lines = []
    for node in ast.walk(tree):
        target = None
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            target = node.func.value
        elif isinstance(node, (ast.Assign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            target = next((t for t in targets if isinstance(t, ast.Attribute)), None)
        if (isinstance(target, ast.Attribute) and target.attr == "path"
                and isinstance(target.value, ast.Name) and target.value.id == "sys"):
            lines.append(node.lineno)
    return sorted(lines)


def test_no_module_edits_sys_path():
    found = {str(p.relative_to(REPO)): lines for p in sources()
             if (lines := edits_sys_path(ast.parse(p.read_text(encoding="utf-8"))))}
    assert found == {}


def test_the_check_can_fail():
    tree = ast.parse("import sys\nsys.path.insert(0, 'x')\nsys.path += ['y']\nsys.path = []\n")
    assert edits_sys_path(tree) == [2, 3, 4]


def test_script_folders_are_packages():
    for folder in ("benchmarks", "studies", "tools"):
        assert (REPO / folder / "__init__.py").is_file(), folder


def unrunnable(text: str) -> list[str]:
    """The commands in ``text`` that would not run: ``python -m X.Y`` without X/Y.py (or a package
    X/Y with __main__.py), and any script of benchmarks/, studies/ or tools/ run by its path
    (they import each other as packages)."""
    bad = []
    for module in sorted(set(RUN_MODULE.findall(text))):
        path = REPO.joinpath(*module.split("."))
        if not (path.with_suffix(".py").is_file() or (path / "__main__.py").is_file()):
            bad.append(module)
    return bad + RUN_SCRIPT.findall(text)


def test_every_module_the_docs_run_exists():
    found = {doc.name: bad for doc in DOCS if (bad := unrunnable(doc.read_text(encoding="utf-8")))}
    assert found == {}
    assert "benchmarks.run_all" in RUN_MODULE.findall((REPO / "Makefile").read_text())


def test_the_docs_check_can_fail():
    text = "python -m studies.no_such_study --out x\n    python studies/validation.py --out v\n"
    assert unrunnable(text) == ["studies.no_such_study", "studies/validation.py"]
