"""The suite's own rules (README, the test command): the default run leaves the tests marked
``slow`` out, ``.ci/run`` runs them right after the README's command, and neither selection
is empty (pytest exits 5 when it selects no test, which would fail CI for nothing run).

The slow tests are counted from the source (``@pytest.mark.slow`` on a test or a
``pytest.param``, ``pytestmark`` of a module), not by collecting the suite again.
"""

from __future__ import annotations

import ast
import shlex
import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:                                                    # pragma: no cover
    tomllib = None

REPO = Path(__file__).resolve().parents[1]
README_COMMAND = 'python3 -m pip install -e ".[test]" && python3 -m pytest'


def _is_slow_mark(node: ast.AST) -> bool:
    """``pytest.mark.slow`` (an attribute chain ending in ``mark.slow``)."""
    return (isinstance(node, ast.Attribute) and node.attr == "slow"
            and isinstance(node.value, ast.Attribute) and node.value.attr == "mark")


def _slow_and_fast(source: str) -> tuple[int, int]:
    """Test functions of a module marked slow (a ``pytest.param`` marked slow counts its
    test once) and not marked slow."""
    tree = ast.parse(source)
    module_slow = any(
        isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "pytestmark"
                                             for t in node.targets)
        and any(_is_slow_mark(n) for n in ast.walk(node.value))
        for node in tree.body)
    slow = fast = 0
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) \
                and node.name.startswith("test_"):
            marked = module_slow or any(_is_slow_mark(n) for d in node.decorator_list
                                        for n in ast.walk(d))
            slow += marked
            fast += not marked
    return slow, fast


def test_slow_mark_counter_counts_a_planted_module():
    source = ("import pytest\n"
              "@pytest.mark.slow\n"
              "def test_a(): pass\n"
              "@pytest.mark.parametrize('n', [1, pytest.param(2, marks=pytest.mark.slow)])\n"
              "def test_b(n): pass\n"
              "def test_c(): pass\n"
              "def helper(): pass\n")
    assert _slow_and_fast(source) == (2, 1)
    assert _slow_and_fast("import pytest\npytestmark = [pytest.mark.slow]\n"
                          "def test_a(): pass\n") == (1, 0)


def test_both_selections_hold_tests():
    counts = [_slow_and_fast(p.read_text(encoding="utf-8"))
              for p in sorted((REPO / "tests").glob("test_*.py"))]
    slow = sum(s for s, _ in counts)
    fast = sum(f for _, f in counts)
    assert slow >= 10 and fast > 4 * slow, (slow, fast)   # most run by default


def test_the_default_run_leaves_the_slow_tests_out():
    text = (REPO / "pyproject.toml").read_text(encoding="utf-8")
    if tomllib is None:                                  # pragma: no cover
        assert "-m 'not slow'" in text
        return
    ini = tomllib.loads(text)["tool"]["pytest"]["ini_options"]
    args = shlex.split(ini["addopts"])
    assert args[args.index("-m") + 1] == "not slow"
    assert any(m.startswith("slow:") for m in ini["markers"])


def test_ci_runs_the_readme_command_then_the_slow_tests_and_all_on_the_oldest():
    assert README_COMMAND in (REPO / "README.md").read_text(encoding="utf-8")
    lines = [line.strip() for line in (REPO / ".ci" / "run").read_text("utf-8").splitlines()
             if line.strip() and not line.lstrip().startswith(("#", "step "))]
    first = lines.index(README_COMMAND)
    assert lines[first + 1] == "python3 -m pytest -m slow"
    oldest = [line for line in lines if "oldest/bin/python" in line and "-m pytest" in line]
    assert len(oldest) == 1 and oldest[0].endswith('-m "slow or not slow"'), oldest
