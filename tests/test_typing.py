"""The public API is typed: every function, method and constructor reachable from the
``__all__`` of :mod:`selfcal` and of its subpackages annotates all its parameters and its
return, dataclass fields are annotated, and the package ships its ``py.typed`` marker
(PEP 561) so that type checkers use these annotations."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import typing
from pathlib import Path

import selfcal

SUBPACKAGES = ("io", "stack", "exposure", "lens", "response", "pipeline", "hdr", "export", "choose",
               "report", "batch", "sim")


def _missing_annotations(func, name: str) -> list[str]:
    """What ``func`` leaves unannotated: ``name(parameter)`` and ``name -> return``."""
    try:
        signature = inspect.signature(func)
    except (TypeError, ValueError):       # a builtin without a signature: nothing to check
        return []
    # the annotations must also resolve (``from __future__ import annotations`` keeps them
    # as strings: a misspelt name shows here)
    typing.get_type_hints(func)
    missing = []
    for i, p in enumerate(signature.parameters.values()):
        if i == 0 and p.name in ("self", "cls"):
            continue
        if p.annotation is inspect.Parameter.empty:
            missing.append(f"{name}({p.name})")
    if signature.return_annotation is inspect.Signature.empty:
        missing.append(f"{name} -> return")
    return missing


def _own_methods(cls) -> dict[str, object]:
    """The public methods (and ``__init__``) that ``cls`` or its selfcal bases define (not
    those of ``object``, ``Exception`` and other bases from outside)."""
    found: dict[str, object] = {}
    for klass in reversed(cls.__mro__):
        if klass is not cls and not klass.__module__.startswith("selfcal"):
            continue
        for attr, value in vars(klass).items():
            if attr.startswith("_") and attr != "__init__":
                continue
            if isinstance(value, (staticmethod, classmethod)):
                value = value.__func__
            if inspect.isfunction(value):
                found[attr] = value
    return found


def unannotated(obj, name: str) -> list[str]:
    """Everything of a public name that a type checker would see as untyped."""
    if inspect.isclass(obj):
        missing = []
        if dataclasses.is_dataclass(obj):
            hints = typing.get_type_hints(obj)
            missing += [f"{name}.{f.name} (field)" for f in dataclasses.fields(obj)
                        if f.name not in hints]
        for attr, method in sorted(_own_methods(obj).items()):
            missing += _missing_annotations(method, f"{name}.{attr}")
        return missing
    if inspect.isfunction(obj):
        return _missing_annotations(obj, name)
    return []           # modules, constants, type aliases


def public_names() -> dict[str, object]:
    """``module.name`` -> object, over ``selfcal.__all__`` and the subpackages' (a
    subpackage without ``__all__``, :mod:`selfcal.stack`, exports nothing of its own)."""
    names = {}
    for module in [selfcal] + [importlib.import_module(f"selfcal.{p}") for p in SUBPACKAGES]:
        for attr in getattr(module, "__all__", ()):
            names[f"{module.__name__}.{attr}"] = getattr(module, attr)
    return names


def test_checker_flags_a_planted_untyped_function():
    def untyped(a, b: int = 1, *args, **kwargs):
        return a

    def typed(a: int, *args: str, **kwargs: float) -> int:
        return a

    assert unannotated(untyped, "untyped") == [
        "untyped(a)", "untyped(args)", "untyped(kwargs)", "untyped -> return"]
    assert unannotated(typed, "typed") == []


def test_checker_flags_a_planted_class():
    @dataclasses.dataclass
    class Planted:
        x: int

        def method(self, y) -> int:
            return y

        def _private(self, z):
            return z

    class Plain:
        def __init__(self, a):
            self.a = a

    assert unannotated(Planted, "Planted") == ["Planted.method(y)"]
    assert unannotated(Plain, "Plain") == ["Plain.__init__(a)", "Plain.__init__ -> return"]


def test_the_public_api_is_fully_annotated():
    names = public_names()
    assert "selfcal.calibrate" in names and "selfcal.hdr.merge_hdr" in names  # the walk saw them
    missing = [m for name, obj in names.items() for m in unannotated(obj, name)]
    assert missing == []


def test_the_package_ships_its_py_typed_marker():
    assert (Path(selfcal.__file__).parent / "py.typed").is_file()
