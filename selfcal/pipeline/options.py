"""The old keyword arguments of the RAW path's functions, mapped onto their options objects.

:func:`~selfcal.pipeline.fit_pipeline`, :func:`~selfcal.pipeline.lattice_regression_lut`,
:func:`~selfcal.pipeline.pairs.pair_samples` and :class:`~selfcal.pipeline.PipelineModel`
take their knobs that travel together as one frozen dataclass.  The keyword arguments they
took before still work, each with a :class:`DeprecationWarning` naming the field to set
instead -- never silently.
"""

from __future__ import annotations

import warnings
from dataclasses import fields, replace


def with_legacy_keywords(options, legacy: dict, function: str, argument: str = "options"):
    """``options`` with the old keyword arguments ``legacy`` of ``function`` applied.

    Each old keyword raises a :class:`DeprecationWarning` naming the field of the options
    class that replaces it; a name that is no field raises TypeError, as Python does for an
    unknown keyword argument.

    Examples
    --------
    >>> import warnings
    >>> from selfcal.pipeline import PipelineOptions
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     opts = with_legacy_keywords(PipelineOptions(), {"n_sets": 5}, "fit_pipeline")
    >>> opts.n_sets, caught[0].category.__name__
    (5, 'DeprecationWarning')
    >>> print(caught[0].message)
    fit_pipeline(n_sets=...) is deprecated: pass options=PipelineOptions(n_sets=...)
    """
    if not legacy:
        return options
    names = {f.name for f in fields(options)}
    for key in legacy:
        if key not in names:
            raise TypeError(f"{function}() got an unexpected keyword argument {key!r}")
    cls = type(options).__name__
    for key in legacy:
        warnings.warn(f"{function}({key}=...) is deprecated: pass "
                      f"{argument}={cls}({key}=...)", DeprecationWarning, stacklevel=3)
    return replace(options, **legacy)
