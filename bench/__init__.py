"""The benchmarks of selfcal: one script per question, run as ``python3 -m bench.<name>``.

Shared code, in one place:

* :mod:`bench.data` -- the real stacks and DoRF curves of ``../shared/data`` (never copied
  into the repository) and the splits they belong to;
* :mod:`bench.peers` -- the methods selfcal is compared with: OpenCV, colour-hdri,
  Mitsunaga & Nayar 1999 (from the paper), ffmpeg's LUT filters;
* :mod:`bench.metrics` -- measures the scripts print beyond :mod:`selfcal.sim.scoring`
  (odd/even agreement of merges, radiance errors against the truth);
* :mod:`bench.tables` -- printing tables and recording each run as JSON in
  ``bench/results/``;
* :mod:`bench.report` -- ``bench/BENCHMARKS.md``, generated from those JSON files.

The library never imports this package, and neither do the tests.
"""
