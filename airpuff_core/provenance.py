"""Where a result came from: the model version and the software that computed it.

**Model version.**  A stored result may be reused only by the model that would compute it again.
``model_version()`` is a hash of the numerical source code of this package: every module of
``airpuff_core`` (kernels included) except those listed in ``NOT_NUMERICAL``, which cannot change
the numbers of a run.  It is taken over the parsed code (``ast``) without docstrings, so editing a
comment or a docstring keeps it, while any change of code -- a constant, a formula, a default, a
new option or a new module -- changes it.  Why a hash and not a number bumped by hand: it cannot
be forgotten, and modules added later (new solver options) are covered without anyone touching
this file.  The price: a change of code that does not change results (a rename, a refactor)
also retires the stored points, which are then computed once more.

**Provenance.**  ``provenance()`` lists what is written into every result file: the airpuff
version, the model version, the git commit of the source tree where known (``"unknown"`` when
the package is not a git checkout or git is missing), and the versions of the libraries that
compute and store the results.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import subprocess
import threading
from importlib import metadata
from pathlib import Path

from .version import __version__

PACKAGE_DIR = Path(__file__).resolve().parent

# Modules that cannot change the numbers of a run: file writing and reading, figures, the
# stability analysis (not used by a run), versions, and the calibration (it maps a run's raw
# readings when a dataset is made; the calibrations themselves are keyed by this hash).  Every
# other module counts.
NOT_NUMERICAL = ("atomic.py", "calibration.py", "dataset.py", "plots.py", "provenance.py",
                 "stability.py", "version.py")

# Libraries whose versions are recorded with every result.
LIBRARIES = ("numpy", "numba", "xarray", "netCDF4", "dask")


def _code_without_docstrings(source: str) -> str:
    """The module's syntax tree as text, docstrings removed (comments are not in the tree)."""
    tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if (body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                    and isinstance(body[0].value.value, str)):
                node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree, annotate_fields=False, include_attributes=False)


def model_version_of(package_dir: Path) -> str:
    """The model version of the package in ``package_dir``: the first 12 hex digits of the
    SHA-256 of its numerical modules (path and code, in path order)."""
    digest = hashlib.sha256()
    for path in sorted(Path(package_dir).rglob("*.py")):
        rel = path.relative_to(package_dir).as_posix()
        if rel in NOT_NUMERICAL:
            continue
        digest.update(rel.encode() + b"\0")
        digest.update(_code_without_docstrings(path.read_text(encoding="utf-8")).encode() + b"\0")
    return digest.hexdigest()[:12]


_model_version: str | None = None
# ``ast.parse`` is not safe to run in two threads at once on every CPython (3.11 raises
# "SystemError: AST constructor recursion depth mismatch"): the hash is computed by one thread
# while the others wait for it.
_model_version_lock = threading.Lock()


def model_version() -> str:
    """The model version of this installation (computed once per process, by one thread)."""
    global _model_version
    if _model_version is None:
        with _model_version_lock:
            if _model_version is None:
                _model_version = model_version_of(PACKAGE_DIR)
    return _model_version


@functools.cache
def git_commit() -> str:
    """The commit of the source tree (``+dirty`` if its tracked files are modified), or
    ``"unknown"`` (no git, not a checkout, or the package is installed elsewhere)."""
    try:
        top = subprocess.run(["git", "rev-parse", "--show-toplevel"], cwd=PACKAGE_DIR,
                             capture_output=True, text=True, timeout=10)
        if top.returncode != 0 or Path(top.stdout.strip()) != PACKAGE_DIR.parent:
            return "unknown"
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=PACKAGE_DIR,
                              capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--",
                                str(PACKAGE_DIR)], cwd=PACKAGE_DIR, capture_output=True,
                               text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    if head.returncode != 0:
        return "unknown"
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def library_versions() -> dict[str, str]:
    """Installed version of each of ``LIBRARIES`` (``"not installed"`` if absent)."""
    out = {}
    for name in LIBRARIES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def provenance() -> dict[str, str]:
    """Global attributes for a result file: ``software_version``, ``model_version``,
    ``git_commit`` and ``<library>_version`` for each of ``LIBRARIES``."""
    attrs = {"software_version": __version__, "model_version": model_version(),
             "git_commit": git_commit()}
    attrs.update({f"{name}_version": v for name, v in library_versions().items()})
    return attrs


# The names of the provenance attributes, in the order of ``provenance()``.
PROVENANCE_ATTRS = ("software_version", "model_version", "git_commit") + tuple(
    f"{name}_version" for name in LIBRARIES)
