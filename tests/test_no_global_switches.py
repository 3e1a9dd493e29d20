"""No module-level variable of the library is assigned from outside its own module.

Behaviour is chosen by arguments (the stages' options objects), never by flipping a
module global (issue 34).  An AST walk over ``selfcal/``, ``selfcal_cli/``, ``bench/`` and
``tests/`` finds, where the target is a selfcal module:

* ``module.NAME = ...`` (also augmented and annotated assignments),
* ``setattr(module, "NAME", ...)``,
* ``monkeypatch.setattr(module, "NAME", ...)`` and
  ``monkeypatch.setattr("selfcal.pkg.module.NAME", ...)``,

where ``module`` is a name bound by ``import selfcal...`` / ``from selfcal... import
module`` (or ``from . import module`` inside the library) in the file.  ``NAME`` is a
variable of the module unless the module binds it by ``def``, ``class`` or ``import``:
replacing a function or class (a spy, a fault) is not a switch.  Attributes of classes are
not module variables.  Planted violations prove each form is caught.
"""

from __future__ import annotations

import ast
import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ("selfcal", "selfcal_cli")


def _module_of(dotted: str) -> Path | None:
    """The source file of a dotted module name of the library, or None."""
    if dotted.split(".")[0] not in LIBRARY:
        return None
    base = ROOT.joinpath(*dotted.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.exists():
            return path
    return None


def _bound_by_definition(module: Path) -> set[str]:
    """Module-level names bound by def, class or import (not variables)."""
    tree = ast.parse(module.read_text(encoding="utf-8"))
    names = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return names


def _package_of(path: Path) -> str | None:
    """The dotted package a library file sits in (for its relative imports)."""
    rel = path.resolve().relative_to(ROOT) if path.resolve().is_relative_to(ROOT) else None
    if rel is None or rel.parts[0] not in LIBRARY:
        return None
    return ".".join(rel.parts[:-1])


def _module_aliases(tree: ast.Module, package: str | None) -> dict[str, str]:
    """Names in a file that refer to library modules: alias -> dotted module name."""
    aliases = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] in LIBRARY:
                    if a.asname:
                        aliases[a.asname] = a.name
                    else:
                        aliases[a.name.split(".")[0]] = a.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                if package is None:
                    continue
                parts = package.split(".")
                parts = parts[:len(parts) - node.level + 1]
                base = ".".join(parts + ([node.module] if node.module else []))
            if base.split(".")[0] not in LIBRARY:
                continue
            for a in node.names:
                dotted = f"{base}.{a.name}"
                if _module_of(dotted) is not None:
                    aliases[a.asname or a.name] = dotted
    return aliases


def _dotted(node: ast.AST, aliases: dict[str, str]) -> str | None:
    """``a.b.c`` as the dotted name it refers to, with ``a`` resolved through the
    aliases (None when ``a`` is no library module)."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name) or node.id not in aliases:
        return None
    return ".".join([aliases[node.id], *reversed(parts)])


def _variable(module_dotted: str, name: str) -> str | None:
    """``module.NAME`` when ``module_dotted`` is a library module and NAME one of its
    variables (not a def, class or import); else None."""
    module = _module_of(module_dotted)
    if module is None or name in _bound_by_definition(module):
        return None
    return f"{module_dotted}.{name}"


def _string_target(value: str) -> str | None:
    """``monkeypatch.setattr("selfcal.pkg.module.NAME", ...)``'s target, if a variable."""
    module, _, name = value.rpartition(".")
    return _variable(module, name) if module else None


def assignments_to_library_globals(source: str, path: Path) -> list[str]:
    """Each assignment in ``source`` to a variable of another library module."""
    tree = ast.parse(source)
    aliases = _module_aliases(tree, _package_of(path))
    own = ".".join(path.resolve().relative_to(ROOT).with_suffix("").parts) \
        if path.resolve().is_relative_to(ROOT) else ""
    found = []

    def check(target_module: str | None, name: str | None, line: int) -> None:
        if target_module is None or name is None:
            return
        hit = _variable(target_module, name)
        if hit is not None and target_module != own.removesuffix(".__init__"):
            found.append(f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}"
                         f":{line}: {hit}")

    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
            targets = [node.target]
        while targets:                      # the assigned attributes, in tuples too
            t = targets.pop()
            if isinstance(t, (ast.Tuple, ast.List)):
                targets.extend(t.elts)
            elif isinstance(t, ast.Attribute):
                check(_dotted(t.value, aliases), t.attr, node.lineno)
        if isinstance(node, ast.Call):
            func = node.func
            is_setattr = ((isinstance(func, ast.Name) and func.id == "setattr")
                          or (isinstance(func, ast.Attribute) and func.attr == "setattr"))
            if not is_setattr or not node.args:
                continue
            first = node.args[0]
            if isinstance(first, ast.Constant) and isinstance(first.value, str):
                hit = _string_target(first.value)       # monkeypatch.setattr("a.b.NAME", v)
                if hit is not None:
                    found.append(f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}"
                                 f":{node.lineno}: {hit}")
            elif (len(node.args) >= 2 and isinstance(node.args[1], ast.Constant)
                  and isinstance(node.args[1].value, str)):
                check(_dotted(first, aliases), node.args[1].value, node.lineno)
    return found


def _scan(folder: str) -> list[str]:
    found = []
    for path in sorted((ROOT / folder).rglob("*.py")):
        if path.name == Path(__file__).name:
            continue                        # the planted violations below are strings
        found += assignments_to_library_globals(path.read_text(encoding="utf-8"), path)
    return found


@pytest.mark.parametrize("folder", ["selfcal", "selfcal_cli", "tests"])
def test_no_library_global_is_assigned_from_outside(folder):
    assert _scan(folder) == []


def test_no_library_global_is_assigned_from_bench():
    if not (ROOT / "bench").is_dir():
        pytest.skip("no bench/ folder")
    assert _scan("bench") == []


PLANTED = {
    "attribute": ("from selfcal.hdr import merge\nmerge.RINGING_RADIUS = 3\n",
                  "selfcal.hdr.merge.RINGING_RADIUS"),
    "augmented": ("import selfcal.hdr.merge as m\nm.RINGING_RADIUS += 1\n",
                  "selfcal.hdr.merge.RINGING_RADIUS"),
    "dotted": ("import selfcal.hdr.merge\nselfcal.hdr.merge.RINGING_RADIUS = 3\n",
               "selfcal.hdr.merge.RINGING_RADIUS"),
    "setattr": ("from selfcal.stack import samples\nsetattr(samples, 'THUMBNAIL_SIDE', 9)\n",
                "selfcal.stack.samples.THUMBNAIL_SIDE"),
    "monkeypatch": ("from selfcal.hdr import weights as w\n"
                    "def test(monkeypatch):\n"
                    "    monkeypatch.setattr(w, 'DEFAULT_NOISE', None)\n",
                    "selfcal.hdr.weights.DEFAULT_NOISE"),
    "monkeypatch string": ("def test(monkeypatch):\n    monkeypatch.setattr("
                           "'selfcal.response.calibrate.MIN_SHARED_SAMPLES', 1)\n",
                           "selfcal.response.calibrate.MIN_SHARED_SAMPLES"),
    "unknown name": ("from selfcal.hdr import merge\nmerge.MERGE_UNCHECKED = False\n",
                     "selfcal.hdr.merge.MERGE_UNCHECKED"),
    "relative, in the library": ("from . import merge\nmerge.RINGING_RADIUS = 0\n",
                                 "selfcal.hdr.merge.RINGING_RADIUS"),
}


@pytest.mark.parametrize("form", list(PLANTED))
def test_a_planted_assignment_is_found(form):
    source, target = PLANTED[form]
    where = ROOT / "selfcal" / "hdr" / "planted.py" if "library" in form \
        else ROOT / "tests" / "planted.py"
    found = assignments_to_library_globals(source, where)
    assert len(found) == 1 and found[0].endswith(f": {target}"), found


@pytest.mark.parametrize("source", [
    # replacing a function (a spy or a fault) is no switch
    "from selfcal.choose import paths\ndef t(monkeypatch):\n"
    "    monkeypatch.setattr(paths, 'fit_pipeline', None)\n",
    # a class attribute is no module variable
    "from selfcal.hdr import accumulate\ndef t(monkeypatch):\n"
    "    monkeypatch.setattr(accumulate.MergeSums, 'unchecked_codes_limit', 0)\n",
    # a module assigning its own variable
    "RINGING_RADIUS = 5\n",
    # an object that is no library module
    "import types\nns = types.SimpleNamespace()\nns.TREND = 'pixels'\n",
])
def test_what_is_not_a_switch_is_not_reported(source):
    assert assignments_to_library_globals(source, ROOT / "selfcal" / "hdr" / "merge.py") == []
