"""gyrorig: experiment design and data fitting for air-bearing gyroscope rigs.

Stages (each a module or package, passing documented pandas DataFrames and frozen dataclasses):

* ``gyrorig.protocols``: experiment files (TOML) -> validated frozen dataclasses.
* ``gyrorig.physics``: singularity-free simulator of the symmetric top / gyrostat,
  composable pivot torques, and the exact (elliptic-function) Lagrange-top solution.
* ``gyrorig.theory``: the paper's formulas, corrected and exact forms.
* ``gyrorig.render``: synthetic video through a camera model, with the truth beside it.
* ``gyrorig.tracking``: video -> tip angles with per-frame covariance.
* ``gyrorig.smooth``: Kalman/RTS smoother.
* ``gyrorig.fit``: least-squares fits against theory.
* ``gyrorig.pipeline``: the chain in memory (``analyze``); ``gyrorig.analysis`` on files.
* ``gyrorig.plan``: what a rig and camera will measure; ``gyrorig.montecarlo`` checks it.

The map of the code is ``docs/architecture.md``.  Conventions (SI units, Goldstein
x-convention Euler angles, gravity along -z) are in ``docs/conventions.md``.
"""

from importlib import import_module
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("gyrorig")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"

# imported on first use, so that ``gyrorig --help`` and ``import gyrorig.cli`` stay light
_LAZY = {"SimulationError": "physics", "exact_solution": "physics", "simulate": "physics",
         "Protocol": "protocols", "ProtocolError": "protocols", "load_protocol": "protocols",
         "parse_protocol": "protocols"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'gyrorig' has no attribute {name!r}")

__all__ = [
    "Protocol",
    "ProtocolError",
    "SimulationError",
    "exact_solution",
    "load_protocol",
    "parse_protocol",
    "simulate",
    "__version__",
]
