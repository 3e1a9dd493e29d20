"""The 1.0 names of the rule for given times, still accepted until 2.0 (CHANGELOG,
"Deprecation policy"): ``refine_exposures=``, ``MergeOptions(measure_exposures=,
linear_exposures=, exposure_trend=)``, each mapped to :class:`.record.ExposureRule` with a
DeprecationWarning that names the replacement.  The one place the mapping lives.

The mapping (the 1.0 combinations the rule no longer has go to the nearest one):

* ``refine_exposures=True`` → ``ExposureRule(refine=True)``; ``False`` →
  ``ExposureRule(times="held")``; ``"auto"`` → the default;
* ``measure_exposures=False`` → ``ExposureRule(times="held")`` (1.0 then merged with the
  given, EXIF or model's exposures as they were); ``True`` → the default;
* ``linear_exposures="times"`` → ``ExposureRule(times="held")``; ``"measured"`` and
  ``"auto"`` → the default (1.0's ``"auto"`` kept the caller's times of a linear bracket:
  the one rule now measures them as it does EXIF times);
* ``exposure_trend=T`` → ``ExposureRule(trend=T)``.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import replace

from ..errors import InputError
from .record import ExposureRule

__all__ = ["LEGACY_NAMES", "rule_from_legacy", "legacy_keywords_accepted"]

#: The 1.0 keywords this module maps.
LEGACY_NAMES = ("refine_exposures", "measure_exposures", "linear_exposures", "exposure_trend")


def rule_from_legacy(legacy: dict, base: ExposureRule | None = None, *,
                     where: str = "", stacklevel: int = 3) -> ExposureRule:
    """``base`` (default ``ExposureRule()``) with the 1.0 keywords of ``legacy`` applied,
    and one DeprecationWarning saying what to write instead.

    Raises
    ------
    InputError
        A value 1.0 did not accept either (named).
    """
    rule = ExposureRule() if base is None else base
    unknown = set(legacy) - set(LEGACY_NAMES)
    if unknown:
        raise TypeError(f"unexpected keyword argument {sorted(unknown)[0]!r}")
    for name, value in legacy.items():
        if name == "refine_exposures":
            if value not in (True, False, "auto"):
                raise InputError(f"refine_exposures must be True, False or 'auto', not "
                                 f"{value!r}")
            if value is True:
                rule = replace(rule, refine=True)
            elif value is False:
                rule = replace(rule, times="held")
        elif name == "measure_exposures":
            if not value:
                rule = replace(rule, times="held")
        elif name == "linear_exposures":
            if value not in ("auto", "measured", "times"):
                raise InputError(f"linear_exposures must be one of auto, measured, times, "
                                 f"not {value!r}")
            if value == "times":
                rule = replace(rule, times="held")
        else:
            rule = replace(rule, trend=value)
    if legacy:
        given = ", ".join(f"{k}={v!r}" for k, v in legacy.items())
        warnings.warn(f"{where}({given}) is the 1.0 form, removed in 2.0: write "
                      f"exposures={rule!r}", DeprecationWarning, stacklevel=stacklevel)
    return rule


def legacy_keywords_accepted(where: str):
    """Let a function with an ``exposures=`` keyword -- or a class whose constructor has
    one (``MergeOptions``) -- also take 1.0's keywords (:data:`LEGACY_NAMES`), with a
    DeprecationWarning: they are folded into ``exposures`` (:func:`rule_from_legacy`).
    The signature shown is unchanged."""
    def decorate(function):
        if isinstance(function, type):      # a class: its constructor
            function.__init__ = decorate(function.__init__)   # type: ignore[misc]
            return function

        @functools.wraps(function)
        def wrapper(*args, **kwargs):
            legacy = {k: kwargs.pop(k) for k in tuple(kwargs) if k in LEGACY_NAMES}
            if legacy:
                kwargs["exposures"] = rule_from_legacy(legacy, kwargs.get("exposures"),
                                                       where=where)
            return function(*args, **kwargs)
        return wrapper
    return decorate
