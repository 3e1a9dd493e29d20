"""The tests never import from ``bench/``: the benchmark scripts may change or go, and what a
test needs lives in the library (e.g. :mod:`selfcal.sim.scoring`) or in a helper module
beside the tests (e.g. ``tests/ffmpeg_lut.py``).  An AST scan of every file under
``tests/``, function-level imports included, with a planted violation to show it finds one.
"""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def bench_imports(source: str) -> list[int]:
    """Line numbers of the statements of ``source`` that import ``bench`` or a module of it."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        if any(n == "bench" or n.startswith("bench.") for n in names):
            lines.append(node.lineno)
    return sorted(lines)


def test_the_scan_finds_a_planted_bench_import():
    planted = ("import numpy\n"
               "from benchmarks import x\n"          # another name: not bench
               "def f():\n"
               "    from bench.metrics import agreement\n"
               "import bench\n"
               "import selfcal, bench.tables as t\n")
    assert bench_imports(planted) == [4, 5, 6]


def test_no_file_under_tests_imports_bench():
    found = {}
    for path in sorted(TESTS.rglob("*.py")):
        lines = bench_imports(path.read_text(encoding="utf-8"))
        if lines:
            found[str(path.relative_to(TESTS))] = lines
    assert not found, f"tests import from bench/ (file: lines): {found}"
