"""The package keeps its layers: imports go one way, and no module grows past 600 lines.

The layers are declared once, as an import-linter contract in ``pyproject.toml``
(``[tool.importlinter]``); docs/architecture.rst explains them.  Within the
layers: no import cycle between modules (function-level imports count), what
modules share has a public name (at most ``MAX_PRIVATE_IMPORTS`` private names
imported from another module), no folder holds more than ``MAX_MODULES``
modules of its own, and no module more than ``MAX_LINES`` lines of code
(docstrings, comments and blank lines left out).  Each check is shown to fail
on a copy of the package, or on sources, made to break it.
"""

import ast
import io
import json
import os
import re
import shutil
import subprocess
import sys
import tokenize

import pytest
from _paths import ROOT

PACKAGE = ROOT / "spherex_reduce"
MAX_LINES = 600
MAX_PRIVATE_IMPORTS = 10
MAX_MODULES = 16

_LINT = (
    "import sys; from importlinter.cli import lint_imports; "
    "sys.exit(lint_imports(config_filename='pyproject.toml', no_cache=True))"
)


def _lint(root):
    """Run the contract of ``root/pyproject.toml`` on ``root/spherex_reduce``."""
    pytest.importorskip(
        "importlinter", reason='the layers check needs import-linter: '
        'python -m pip install -e ".[test]" installs it')
    env = dict(os.environ, PYTHONPATH=str(root))
    env.pop("PYTHONWARNINGS", None)
    return subprocess.run([sys.executable, "-c", _LINT], cwd=root, env=env,
                          capture_output=True, text=True, timeout=120)


def test_imports_follow_the_layers():
    result = _lint(ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert re.search(r"Contracts: [1-9]\d* kept, 0 broken", result.stdout), result.stdout


def _copy(tmp_path):
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    pkg = tmp_path / "spherex_reduce"
    shutil.copytree(PACKAGE, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    return pkg


def test_an_upward_import_breaks_the_contract(tmp_path):
    # The check can fail: a copy of the package where a core module imports a
    # step inside a function (where it would dodge an import cycle) is refused.
    pkg = _copy(tmp_path)
    with open(pkg / "core" / "geometry.py", "a") as f:
        f.write("\n\ndef _upward():\n    from ..reduce.steps import unchop\n\n    return unchop\n")
    result = _lint(tmp_path)
    assert result.returncode != 0
    assert "spherex_reduce.core is not allowed to import spherex_reduce.reduce" in result.stdout
    assert "spherex_reduce.core.geometry -> spherex_reduce.reduce.steps.unchop" in result.stdout


def test_a_module_outside_the_layers_breaks_the_contract(tmp_path):
    # and so is a new top-level module that no layer names
    pkg = _copy(tmp_path)
    (pkg / "unplaced.py").write_text("X = 1\n")
    result = _lint(tmp_path)
    assert result.returncode != 0
    assert "- spherex_reduce.unplaced" in result.stdout



# -- import cycles -----------------------------------------------------------------
_CYCLES = """\
import json
import grimp

graph = grimp.build_graph("spherex_reduce", cache_dir=None)
index, low, stack, on_stack, cycles = {}, {}, [], set(), []
for root in sorted(graph.modules):  # Tarjan's strongly connected components, iteratively
    if root in index:
        continue
    index[root] = low[root] = len(index)
    stack.append(root)
    on_stack.add(root)
    work = [(root, iter(sorted(graph.find_modules_directly_imported_by(root))))]
    while work:
        node, children = work[-1]
        for child in children:
            if child not in index:
                index[child] = low[child] = len(index)
                stack.append(child)
                on_stack.add(child)
                work.append((child, iter(sorted(graph.find_modules_directly_imported_by(child)))))
                break
            if child in on_stack:
                low[node] = min(low[node], index[child])
        else:
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    cycles.append(sorted(component))
print(json.dumps({"modules": len(graph.modules), "cycles": sorted(cycles)}))
"""


def _cycles(root):
    """The import cycles (strongly connected modules) of ``root/spherex_reduce``."""
    pytest.importorskip("grimp", reason="the cycle check needs grimp (installed with "
                        'import-linter: python -m pip install -e ".[test]")')
    env = dict(os.environ, PYTHONPATH=str(root))
    env.pop("PYTHONWARNINGS", None)
    done = subprocess.run([sys.executable, "-c", _CYCLES], cwd=root, env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_no_import_cycle_between_modules():
    found = _cycles(ROOT)
    assert found["modules"] > 50  # the graph holds the package
    assert found["cycles"] == []


def test_a_planted_cycle_is_found(tmp_path):
    # an import inside a function (where a cycle hides from the import system) counts
    pkg = _copy(tmp_path)
    with open(pkg / "core" / "errors.py", "a") as f:
        f.write("\n\ndef _back():\n    from .limits import check_count\n\n    return check_count\n")
    found = _cycles(tmp_path)
    assert found["cycles"] == [["spherex_reduce.core.errors", "spherex_reduce.core.limits"]]


# -- private names shared ------------------------------------------------------------
def _module_name(path, package):
    parts = list(path.relative_to(package.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def private_imports(package):
    """``(importer, module, name)`` of every private name a module imports from another one.

    Private: one leading underscore (``__version__`` and the like are not).  An
    import of a private submodule (``from . import _x``) counts too.
    """
    found = []
    for path in sorted(package.rglob("*.py")):
        importer = _module_name(path, package)
        here = importer if path.name == "__init__.py" else importer.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.ImportFrom):
                continue
            if node.level:
                parts = here.split(".")
                base = parts[:len(parts) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            if module.split(".")[0] != package.name or module == importer:
                continue
            found += [(importer, module, a.name) for a in node.names
                      if a.name.startswith("_") and not a.name.startswith("__")]
    return found


def test_modules_share_public_names():
    found = private_imports(PACKAGE)
    listing = "\n".join(" ".join(row) for row in found)
    assert len(found) <= MAX_PRIVATE_IMPORTS, f"private names imported across modules:\n{listing}"


def test_private_imports_are_counted(tmp_path):
    # the walk sees relative and absolute imports, of names and of private submodules,
    # and not a module's import of itself nor a dunder
    pkg = _copy(tmp_path)
    (pkg / "core" / "planted.py").write_text(
        "from spherex_reduce.core.limits import _a\n"
        "from .errors import _b, __c__\n"
        "from ..io import _d\n"
        "from . import _e\n"
        "from .planted import _f\n")
    planted = [row[1:] for row in private_imports(pkg) if row[0] == "spherex_reduce.core.planted"]
    assert planted == [("spherex_reduce.core.limits", "_a"), ("spherex_reduce.core.errors", "_b"),
                       ("spherex_reduce.io", "_d"), ("spherex_reduce.core", "_e")]
    for k in range(MAX_PRIVATE_IMPORTS + 1):
        (pkg / "core" / f"planted_{k}.py").write_text(f"from .limits import _private_{k}\n")
    assert len(private_imports(pkg)) > MAX_PRIVATE_IMPORTS


# -- modules per folder --------------------------------------------------------------
def modules_per_folder(package):
    """``{folder: modules}`` of every package folder (its ``__init__`` not counted)."""
    folders = [package, *sorted(d for d in package.rglob("*") if d.is_dir())]
    return {folder.relative_to(package.parent).as_posix():
            sum(1 for p in folder.glob("*.py") if p.name != "__init__.py")
            for folder in folders if (folder / "__init__.py").exists()}


def test_no_folder_over_16_modules():
    counts = modules_per_folder(PACKAGE)
    assert counts["spherex_reduce/core"] > 5  # the walk found the folders
    offenders = {name: n for name, n in counts.items() if n > MAX_MODULES}
    assert not offenders, f"folders over {MAX_MODULES} modules: {offenders}"


def test_a_crowded_folder_is_counted(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__pycache__").mkdir()  # not a package folder
    for folder, n in ((pkg, 3), (pkg / "sub", MAX_MODULES + 1)):
        (folder / "__init__.py").write_text("")
        for k in range(n):
            (folder / f"m{k}.py").write_text("X = 1\n")
    assert modules_per_folder(pkg) == {"pkg": 3, "pkg/sub": MAX_MODULES + 1}


# -- lines of code per module --------------------------------------------------------
_NOT_CODE = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT,
             tokenize.ENCODING, tokenize.ENDMARKER}


def code_lines(text):
    """Lines of ``text`` (Python source) that hold code: not blank, comment or docstring."""
    docstrings = set()
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            first = node.body[0] if node.body else None
            if (isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
                    and isinstance(first.value.value, str)):
                docstrings.add((first.lineno, first.col_offset))
    lines = set()
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type in _NOT_CODE or (tok.type == tokenize.STRING and tok.start in docstrings):
            continue
        lines.update(range(tok.start[0], tok.end[0] + 1))
    return len(lines)


def test_no_module_over_600_lines_of_code():
    sizes = {p.relative_to(ROOT).as_posix(): code_lines(p.read_text(encoding="utf-8"))
             for p in sorted(PACKAGE.rglob("*.py"))}
    assert len(sizes) > 50  # the walk found the package
    offenders = {name: n for name, n in sizes.items() if n > MAX_LINES}
    assert not offenders, f"modules over {MAX_LINES} lines of code: {offenders}"


SOURCE = '''\
"""Module docstring,

on three lines."""

# a comment
X = """a string that is data,
two lines"""  # counted


class A:
    """Class docstring."""

    def f(self, x,
          y):
        """Function
        docstring."""
        return (x +  # a comment after code
                y)
'''


def test_code_lines_leave_out_docstrings_comments_and_blanks():
    # X (2 lines), class A, def f (2 lines), return (2 lines)
    assert code_lines(SOURCE) == 7
    assert code_lines("\n".join(f"x{k} = {k}" for k in range(MAX_LINES + 1))) == MAX_LINES + 1
    assert code_lines('"""Doc."""\n' + "# note\n\n" * MAX_LINES) == 0
