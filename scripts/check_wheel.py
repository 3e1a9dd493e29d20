#!/usr/bin/env python3
"""Check a built wheel against the source tree: every package, module and data file there.

The wheel is what ``pip install .`` gives a user; the source tree is what the tests import.
A package left out of the wheel (as ``selfcal.response.curve_family`` once was, from a hand
list in ``pyproject.toml``) passes every test run from the tree and fails on the user's
machine, so ``.ci/run`` runs this on the wheel it builds.

Checked: every file of the importable packages (``selfcal/``, ``selfcal_cli/``: modules,
``py.typed``, the basis ``.npz``; caches and compiled files aside) is in the wheel at the same
path, and the wheel declares the ``selfcal`` console script.

Usage::

    python scripts/check_wheel.py dist/selfcal-1.0.0-py3-none-any.whl [--root .]

Exit 0 when nothing is missing; exit 1 with one line per missing file, package or entry
point; exit 2 when the wheel cannot be read.
"""

from __future__ import annotations

import argparse
import configparser
import sys
import zipfile
from pathlib import Path

#: The folders of the source tree that are installed as top-level packages.
PACKAGE_ROOTS = ("selfcal", "selfcal_cli")
#: What is never shipped: byte-code caches.
IGNORED_PARTS = ("__pycache__",)
IGNORED_SUFFIXES = (".pyc", ".pyo")
CONSOLE_SCRIPT = "selfcal"


def source_files(root: Path) -> list[str]:
    """Paths (relative to ``root``, ``/``-separated) of the files the wheel must carry."""
    found = []
    for top in PACKAGE_ROOTS:
        for path in sorted((root / top).rglob("*")):
            rel = path.relative_to(root)
            if (path.is_file() and not any(p in IGNORED_PARTS for p in rel.parts)
                    and path.suffix not in IGNORED_SUFFIXES):
                found.append(rel.as_posix())
    return found


def _console_scripts(wheel: zipfile.ZipFile) -> set[str]:
    names = [n for n in wheel.namelist() if n.endswith(".dist-info/entry_points.txt")]
    if not names:
        return set()
    parser = configparser.ConfigParser()
    parser.read_string(wheel.read(names[0]).decode())
    return set(parser["console_scripts"]) if parser.has_section("console_scripts") else set()


def missing_from_wheel(wheel_path: Path, root: Path) -> list[str]:
    """What the wheel lacks: ``package X``, ``file Y`` and ``console script Z`` lines.

    A package counts as missing when its ``__init__.py`` is; its other files are then not
    listed one by one.
    """
    with zipfile.ZipFile(wheel_path) as wheel:
        shipped = set(wheel.namelist())
        scripts = _console_scripts(wheel)
    wanted = source_files(root)
    absent_packages = sorted(name.rsplit("/", 1)[0] for name in wanted
                             if name.endswith("/__init__.py") and name not in shipped)
    problems = [f"package {p.replace('/', '.')} (folder {p}/)" for p in absent_packages]
    for name in wanted:
        if name not in shipped and name.rsplit("/", 1)[0] not in absent_packages:
            problems.append(f"file {name}")
    if CONSOLE_SCRIPT not in scripts:
        problems.append(f"console script {CONSOLE_SCRIPT!r} (entry_points.txt)")
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("wheel", type=Path, help="the built .whl file")
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1],
                        help="the source tree (default: this repository)")
    args = parser.parse_args(argv)
    try:
        problems = missing_from_wheel(args.wheel, args.root)
    except (OSError, zipfile.BadZipFile) as exc:
        print(f"check_wheel: {args.wheel}: cannot be read as a wheel ({exc})", file=sys.stderr)
        return 2
    if problems:
        print(f"check_wheel: {args.wheel.name} lacks what the source tree has:",
              file=sys.stderr)
        for line in problems:
            print(f"  {line}", file=sys.stderr)
        return 1
    print(f"check_wheel: {args.wheel.name} holds all {len(source_files(args.root))} files "
          f"of {', '.join(PACKAGE_ROOTS)} and the {CONSOLE_SCRIPT!r} command")
    return 0


if __name__ == "__main__":
    sys.exit(main())
