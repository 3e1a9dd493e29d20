"""The release: the wheel a user installs holds the whole source tree, and one version.

The wheels here are built for real (setuptools, as ``pip install .`` does) from a copy of
the tree in a temporary folder, so the repository is left as it was; ``.ci/run`` also builds
the sdist and the wheel with ``python -m build`` and installs the wheel in a new virtual
environment.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import selfcal

REPO = Path(__file__).resolve().parents[1]
CHECK = REPO / "scripts" / "check_wheel.py"
#: What building the wheel reads from the tree.
BUILD_INPUTS = ("pyproject.toml", "README.md", "LICENSE", "selfcal", "selfcal_cli")


def _project_version() -> str:
    # the [project] table's version line (tomllib is Python >= 3.11 only)
    found = re.search(r'^\[project\]$(?:(?!^\[).)*?^version = "([^"]+)"$',
                      (REPO / "pyproject.toml").read_text(), re.M | re.S)
    assert found, "no version in pyproject.toml's [project] table"
    return found.group(1)


def _copy_tree(dest: Path) -> Path:
    dest.mkdir()
    for name in BUILD_INPUTS:
        src = REPO / name
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(src, dest / name)
    return dest


def _build_wheel(tree: Path, out: Path) -> Path:
    # --no-build-isolation: the test extra installs setuptools and wheel, so no download
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
         "-w", str(out), str(tree)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    (wheel,) = out.glob("selfcal-*.whl")
    return wheel


def _check(wheel: Path, root: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(CHECK), str(wheel), "--root", str(root)],
                          capture_output=True, text=True, timeout=60)


def test_the_wheel_of_the_tree_holds_every_package(tmp_path):
    tree = _copy_tree(tmp_path / "tree")
    wheel = _build_wheel(tree, tmp_path / "dist")
    done = _check(wheel, tree)
    assert done.returncode == 0, done.stderr
    assert "selfcal-" + _project_version() in wheel.name
    with zipfile.ZipFile(wheel) as shipped:          # read back independently of the check
        names = set(shipped.namelist())
    for name in ("selfcal/data/response_basis.npz", "selfcal/py.typed",
                 "selfcal/response/curve_family/__init__.py", "selfcal_cli/main.py"):
        assert name in names


def test_the_check_names_a_package_left_out_of_the_wheel(tmp_path):
    # the omission that once shipped: a hand list of packages without the sub-package
    tree = _copy_tree(tmp_path / "tree")
    packages = sorted(p.parent.relative_to(tree).as_posix().replace("/", ".")
                      for top in ("selfcal", "selfcal_cli")
                      for p in (tree / top).rglob("__init__.py"))
    assert "selfcal.response.curve_family" in packages
    hand_list = [p for p in packages if p != "selfcal.response.curve_family"]
    pyproject = (tree / "pyproject.toml").read_text()
    found_rule = re.search(r"\[tool\.setuptools\.packages\.find\]\n(?:[^\[\n].*\n)+", pyproject)
    assert found_rule, "pyproject.toml no longer finds its packages with setuptools' rule"
    planted = pyproject.replace(found_rule.group(0),
                                f"[tool.setuptools]\npackages = {json.dumps(hand_list)}\n\n")
    (tree / "pyproject.toml").write_text(planted)
    wheel = _build_wheel(tree, tmp_path / "dist")
    done = _check(wheel, tree)
    assert done.returncode == 1
    assert "package selfcal.response.curve_family" in done.stderr
    assert "selfcal.response.model" not in done.stderr      # only what is missing


def test_the_check_says_when_a_file_is_not_a_wheel(tmp_path):
    bad = tmp_path / "selfcal-1.0.0-py3-none-any.whl"
    bad.write_bytes(b"not a zip")
    done = _check(bad, REPO)
    assert done.returncode == 2
    assert str(bad) in done.stderr and "cannot be read as a wheel" in done.stderr


def test_one_version_for_the_package_the_command_and_the_changelog():
    version = _project_version()
    assert selfcal.__version__ == version
    done = subprocess.run([sys.executable, "-m", "selfcal_cli", "--version"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0
    assert done.stdout.strip() == f"selfcal {version}"
    changelog = (REPO / "CHANGELOG.md").read_text()
    released = re.findall(r"^## \[(\d+\.\d+\.\d+)\] - \d{4}-\d{2}-\d{2}$", changelog, re.M)
    assert released and released[0] == version, "the newest CHANGELOG entry is not this version"


def test_model_files_record_the_release_that_wrote_them_and_older_files_load(tmp_path):
    model = selfcal.calibrate_response(
        [str(p) for p in sorted((REPO / "fixtures" / "stack").glob("*.jpg"))])
    path = model.save(tmp_path / "model.json")
    doc = json.loads(Path(path).read_text())
    assert doc["selfcal_version"] == selfcal.__version__
    assert doc["version"] >= 2                       # the format's version is kept beside it
    del doc["selfcal_version"]                        # as written before 1.0.0
    old = tmp_path / "old.json"
    old.write_text(json.dumps(doc))
    again = selfcal.load_model(old)
    assert again.intensity.shape == model.intensity.shape


@pytest.mark.parametrize("name", ["py.typed", "data/response_basis.npz"])
def test_package_data_is_in_the_source_tree(name):
    # the wheel check compares against the tree: the tree must hold what is shipped
    assert (REPO / "selfcal" / name).is_file()
