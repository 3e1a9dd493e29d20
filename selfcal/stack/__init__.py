"""A bracketed stack before any model: its frames, their alignment, their correspondences.

* :mod:`selfcal.stack.frames` -- a stack's frames, clip limits, linearisers and exposures,
  shared by the response path and the merge;
* :mod:`selfcal.stack.align` -- MTB / ECC / feature alignment;
* :mod:`selfcal.stack.samples` -- block-mean correspondences across a stack and their
  outlier masks with reasons ([Lin2011]_ §5: clipped and saturated samples);
* :mod:`selfcal.stack.linear_evidence` -- whether 16-bit or float TIFFs are linear data.

References
----------
.. [Lin2011] See ``docs/references.md``.
"""
