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

from .physics import SimulationError, exact_solution, simulate
from .protocols import Protocol, ProtocolError, load_protocol, parse_protocol

__version__ = "0.1.0"

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
