"""Benchmarks that print figures (``gyrorig bench ...``), not timed unit tests.

* :mod:`~gyrorig.bench.methods`: the simulator's error against run time (``bench methods``, ``bench accuracy``);
* :mod:`~gyrorig.bench.stability`: stiff and extreme cases (``bench stability``);
* :mod:`~gyrorig.bench.throughput`: rendering, tracking and smoothing speed and precision (``bench render``,
  ``bench track``, ``bench smooth``);
* :mod:`~gyrorig.bench.variants`: tracking footage unlike the tracker's own assumptions (``bench variants``).

The fit benchmark (``bench fit``) is the Monte Carlo of the full chain, :mod:`gyrorig.montecarlo`.
"""

from .methods import DEFAULT_COMPARE_METHODS, accuracy_scenes, benchmark_top, compare_methods, speed_ratio, work_precision
from .stability import AGREEMENT_TOL_RAD, INVARIANT_RTOL, run_stability, verdicts
from .throughput import render_throughput, smooth_benchmark, track_benchmark

__all__ = ["DEFAULT_COMPARE_METHODS", "accuracy_scenes", "benchmark_top", "compare_methods", "speed_ratio",
           "work_precision", "AGREEMENT_TOL_RAD", "INVARIANT_RTOL", "run_stability", "verdicts", "render_throughput",
           "smooth_benchmark", "track_benchmark"]
