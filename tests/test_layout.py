"""The house rules of the source tree (README, "Pieces"), checked on the code itself.

- the library is in floors: no module of ``selfcal/`` imports one on a floor above its
  own (function-level imports count), and nothing imports ``selfcal_cli/``;
- no module of ``selfcal/`` or ``selfcal_cli/`` imports one that imports it back;
- no public function with more than 10 parameters -- the simulator included;
- no private name of one module read in another: neither imported (``from m import _x``)
  nor read as an attribute (``obj._x``, ``getattr(obj, "_x")``) of anything but ``self``
  or ``cls`` where ``_x`` is not defined in the reading module (the privates of the
  standard library and of third-party modules, ``os._exit``, are not this rule's);
- an alarm, not a budget: a module over 1,000 lines or a function body over 150 lines
  (its docstring not counted) fails.  The limits are far above what a module or function
  of this tree needs, so that nobody trims lines to fit under them; a failure means a
  module or a function has grown into several, not that it wants a few lines shorter.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = {"selfcal": REPO / "selfcal", "selfcal_cli": REPO / "selfcal_cli"}
#: the alarms of the size rules (module docstring): far above every module and function of
#: the tree, so that a failure means something grew into two, never a count to trim to
MAX_FUNCTION_BODY_LINES = 150
MAX_MODULE_LINES = 1000
MAX_PARAMETERS = 10
#: The floors of the library, lowest first (README's table says the same).  A module may
#: import modules of its own floor and of the floors below it.
FLOORS = (
    ("selfcal.errors", "selfcal.version", "selfcal.typing"),
    ("selfcal.io",),
    ("selfcal.stack",),
    # a bracket's exposures are one room above the frames: stack never imports exposure
    ("selfcal.exposure", "selfcal.lens"),
    ("selfcal.response", "selfcal.pipeline"),
    ("selfcal.hdr", "selfcal.export"),
    ("selfcal.choose", "selfcal.report"),
    ("selfcal.batch",),
    ("selfcal.sim",),
)


def _modules() -> dict[str, Path]:
    found = {}
    for package, root in PACKAGES.items():
        for path in sorted(root.rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join([package, *parts])] = path
    return found


def _resolve(module: str, path: Path, node: ast.ImportFrom) -> list[str]:
    """Absolute names a ``from ... import ...`` statement can refer to."""
    if node.level:
        package = module.split(".")
        if path.name != "__init__.py":
            package = package[:-1]
        package = package[: len(package) - (node.level - 1)]
        base = ".".join(package + ([node.module] if node.module else []))
    else:
        base = node.module or ""
    return [base] + [f"{base}.{alias.name}" for alias in node.names]


def _import_graph() -> dict[str, set[str]]:
    modules = _modules()
    graph = {}
    for name, path in modules.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                candidates = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                candidates = _resolve(name, path, node)
            else:
                continue
            targets.update(c for c in candidates if c in modules and c != name)
        graph[name] = targets
    # A package's __init__ re-exporting its own modules is not a circle of rooms:
    # importing selfcal.hdr.merge runs selfcal.hdr's __init__ first by Python's rules.
    for name in graph:
        graph[name] = {t for t in graph[name] if not name.startswith(t + ".")}
    return _with_parent_packages(graph)


def _with_parent_packages(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """Importing ``a.b.c`` runs package ``a.b``'s ``__init__`` first: an edge to each parent
    package of a target (below the top package, and not one of the importer's own)."""
    out = {name: set(targets) for name, targets in graph.items()}
    for name, targets in graph.items():
        for target in targets:
            parts = target.split(".")
            for i in range(2, len(parts)):
                parent = ".".join(parts[:i])
                if parent in graph and parent != name and not name.startswith(parent + "."):
                    out[name].add(parent)
    return out


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, on_stack, stack, found = {}, {}, set(), [], []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
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
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _stale_imports() -> list[str]:
    """Imports of selfcal modules that do not exist (a function-level one fails only when
    it runs, and a caller that catches everything hides it)."""
    modules = _modules()
    stale = []
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                base = _resolve(name, path, node)[0]
            elif isinstance(node, ast.Import):
                base = node.names[0].name
            else:
                continue
            root = base.split(".")[0]
            if root in PACKAGES and base not in modules:
                stale.append(f"{name}:{node.lineno} imports {base}")
    return stale


def test_every_import_of_the_library_names_a_module_that_exists():
    assert _stale_imports() == []


def test_cycle_finder_finds_a_planted_circle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_cycle_finder_sees_a_circle_through_a_package_init():
    # an __init__ importing its module that imports, through another package, a sibling
    graph = {"selfcal.exposure": {"selfcal.exposure.linear"},
             "selfcal.exposure.linear": {"selfcal.stack.linear_evidence"},
             "selfcal.stack.linear_evidence": {"selfcal.exposure.raw_ratios"},
             "selfcal.exposure.raw_ratios": set()}
    assert _cycles(graph) == []
    assert _cycles(_with_parent_packages(graph)) != []


def test_no_import_circles():
    graph = _import_graph()
    assert "selfcal.response.calibrate" in graph  # the walk saw the tree
    assert _cycles(graph) == []


def _floor(module: str) -> int | None:
    for level, rooms in enumerate(FLOORS):
        if any(module == room or module.startswith(room + ".") for room in rooms):
            return level
    return None


def _upward_imports(graph: dict[str, set[str]]) -> list[str]:
    found = []
    for name, targets in graph.items():
        if not name.startswith("selfcal.") or _floor(name) is None:
            continue
        for target in sorted(targets):
            if target.startswith("selfcal_cli"):
                found.append(f"{name} -> {target} (the command line)")
            elif _floor(target) is not None and _floor(target) > _floor(name):
                found.append(f"{name} (floor {_floor(name)}) -> {target} "
                             f"(floor {_floor(target)})")
    return found


def test_floor_check_finds_a_planted_upward_import():
    assert _upward_imports({"selfcal.io.images": {"selfcal.hdr.merge"}}) == [
        "selfcal.io.images (floor 1) -> selfcal.hdr.merge (floor 5)"]
    assert _upward_imports({"selfcal.hdr.merge": {"selfcal.io.images"}}) == []


def test_every_library_module_is_on_a_floor():
    graph = _import_graph()
    loose = [m for m in graph if m.startswith("selfcal.") and _floor(m) is None]
    assert loose == []


def test_no_module_imports_one_on_a_floor_above():
    assert _upward_imports(_import_graph()) == []


def _function_nodes():
    for name, path in _modules().items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield name, node


def _body_lines(node) -> int:
    """Lines of a function's body: its signature and its docstring not counted."""
    body = node.body
    first = body[0]
    if (len(body) > 1 and isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
            and isinstance(first.value.value, str)):
        body = body[1:]
    return node.end_lineno - body[0].lineno + 1


def _parameters(node) -> int:
    args = node.args
    names = [*args.posonlyargs, *args.args, *args.kwonlyargs]
    count = len(names) + (args.vararg is not None) + (args.kwarg is not None)
    return count - (1 if names and names[0].arg in ("self", "cls") else 0)


def test_body_lines_count_neither_signature_nor_docstring():
    node = ast.parse('def f(\n    a,\n):\n    """Doc.\n\n    More.\n    """\n    x = a\n'
                     '    return x\n').body[0]
    assert _body_lines(node) == 2


def test_no_function_body_over_the_alarm():
    long = [f"{name}.{node.name}: {_body_lines(node)} lines"
            for name, node in _function_nodes() if _body_lines(node) > MAX_FUNCTION_BODY_LINES]
    assert long == []


def test_no_public_function_with_too_many_parameters():
    many = [f"{name}.{node.name}: {_parameters(node)}" for name, node in _function_nodes()
            if (not node.name.startswith("_") or node.name == "__init__")
            and _parameters(node) > MAX_PARAMETERS]
    assert many == []


def test_no_module_over_the_alarm():
    lengths = {name: path.read_text(encoding="utf-8").count("\n")
               for name, path in _modules().items()}
    assert len(lengths) > 50  # the walk saw the tree
    assert {name: n for name, n in lengths.items() if n > MAX_MODULE_LINES} == {}


def _private_imports(source: str, module: str, path: Path) -> list[str]:
    """``from M import _name`` in ``module`` where ``M`` is another module: a private name
    used outside the module that defines it (module aliases such as ``import x as _x`` and
    dunders are fine)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.ImportFrom) or node.module == "__future__":
            continue
        target = _resolve(module, path, node)[0]
        if target == module:
            continue
        found += [f"{module} imports {target}.{alias.name}" for alias in node.names
                  if alias.name.startswith("_") and not alias.name.startswith("__")]
    return found


def test_private_import_check_finds_a_planted_one():
    path = REPO / "selfcal" / "hdr" / "merge.py"
    planted = "from .deghost import _ghost_mask, ghost_free\nfrom . import weights as _w\n"
    assert _private_imports(planted, "selfcal.hdr.merge", path) == [
        "selfcal.hdr.merge imports selfcal.hdr.deghost._ghost_mask"]


def test_no_private_name_is_imported_from_another_module():
    found = [line for name, path in _modules().items()
             for line in _private_imports(path.read_text(encoding="utf-8"), name, path)]
    assert found == []


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _defined_names(tree: ast.AST) -> set[str]:
    """Every name a module defines: functions, classes, assigned names and attributes
    (``self._x = ...``, ``obj._x = ...``), parameters and import aliases."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, (ast.Store, ast.Del)):
            names.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, (ast.Store, ast.Del)):
            names.add(node.attr)
        elif isinstance(node, ast.arg):
            names.add(node.arg)
        elif isinstance(node, ast.alias):
            names.add(node.asname or node.name.split(".")[0])
    return names


def _outside_imports(tree: ast.AST, module: str, path: Path) -> set[str]:
    """The names a module binds to modules outside ``selfcal/`` and ``selfcal_cli/``
    (``import os``, ``from concurrent import futures``)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update((a.asname or a.name.split(".")[0]) for a in node.names
                         if a.name.split(".")[0] not in PACKAGES)
        elif isinstance(node, ast.ImportFrom) and not node.level:
            if (node.module or "").split(".")[0] not in PACKAGES:
                names.update(a.asname or a.name for a in node.names)
    return names


def _root_name(node: ast.AST) -> str | None:
    while isinstance(node, (ast.Attribute, ast.Subscript, ast.Call)):
        node = node.func if isinstance(node, ast.Call) else node.value
    return node.id if isinstance(node, ast.Name) else None


def _private_attribute_reads(source: str, module: str, path: Path) -> list[str]:
    """``obj._name`` (and ``getattr(obj, "_name")``) read in ``module`` where ``obj`` is
    not ``self`` or ``cls`` and ``_name`` is defined nowhere in ``module``: another module's
    private read through one of its objects."""
    tree = ast.parse(source)
    defined = _defined_names(tree)
    outside = _outside_imports(tree, module, path)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Load):
            owner, attr = node.value, node.attr
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
              and node.func.id in ("getattr", "hasattr") and len(node.args) >= 2
              and isinstance(node.args[1], ast.Constant)
              and isinstance(node.args[1].value, str)):
            owner, attr = node.args[0], node.args[1].value
        else:
            continue
        if not _is_private(attr) or attr in defined:
            continue
        root = _root_name(owner)
        if (isinstance(owner, ast.Name) and root in ("self", "cls")) or root in outside:
            continue
        found.append((node.lineno, node.col_offset,
                      f"{module}:{node.lineno} reads {ast.unparse(owner)}.{attr}"))
    return [line for _, _, line in sorted(found)]


def test_private_attribute_check_finds_a_planted_one():
    path = REPO / "selfcal" / "sim" / "cards.py"
    planted = ("import os\n"
               "from . import stacks as _stacks\n"
               "class Card:\n"
               "    def __init__(self):\n"
               "        self._own = 1\n"
               "    def own(self, other):\n"
               "        return self._own + other._own + self._inherited\n"
               "def write(stack):\n"
               "    os._exit(0)\n"
               "    _stacks.simulate_stack\n"
               "    return stack._encoded[0], getattr(stack, '_frames'), stack.__dict__\n")
    assert _private_attribute_reads(planted, "selfcal.sim.cards", path) == [
        "selfcal.sim.cards:11 reads stack._encoded",
        "selfcal.sim.cards:11 reads stack._frames"]


def test_no_private_attribute_of_another_module_is_read():
    found = [line for name, path in _modules().items()
             for line in _private_attribute_reads(path.read_text(encoding="utf-8"), name,
                                                  path)]
    assert found == []


def _unlisted_modules(package_dir: Path, package: str) -> list[str]:
    """Modules and sub-packages of a package that its docstring does not name on a line of
    their own (``* :mod:`package.name` -- ...``)."""
    doc = ast.get_docstring(ast.parse((package_dir / "__init__.py").read_text("utf-8"))) or ""
    listed = set(re.findall(r"^\* :mod:`([\w.]+)`", doc, re.M))
    members = sorted([p.stem for p in package_dir.glob("*.py") if not p.stem.startswith("_")]
                     + [p.name for p in package_dir.iterdir() if (p / "__init__.py").is_file()])
    return [f"{package}.{m}" for m in members if f"{package}.{m}" not in listed]


def test_unlisted_module_check_finds_a_planted_one(tmp_path):
    (tmp_path / "__init__.py").write_text('"""A package.\n\n* :mod:`pkg.kept` -- here.\n"""\n')
    (tmp_path / "kept.py").write_text("")
    (tmp_path / "forgotten.py").write_text("")
    assert _unlisted_modules(tmp_path, "pkg") == ["pkg.forgotten"]


def test_every_package_docstring_lists_its_modules():
    unlisted = [name for init in sorted((REPO / "selfcal").rglob("__init__.py"))
                for name in _unlisted_modules(
                    init.parent, ".".join(init.parent.relative_to(REPO).parts))]
    assert unlisted == []
