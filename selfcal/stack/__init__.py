"""A bracketed stack before any model: its frames, their alignment, their correspondences.

* :mod:`selfcal.stack.frames` -- a stack's frames, clip limits and linearisers, shared by
  the response path and the merge (their exposures are :mod:`selfcal.exposure`'s);
* :mod:`selfcal.stack.align` -- MTB / ECC / feature alignment;
* :mod:`selfcal.stack.samples` -- block-mean correspondences across a stack and their
  outlier masks with reasons ([Lin2011]_ §5: clipped and saturated samples);

References
----------
.. [Lin2011] See ``docs/references.md``.
"""
