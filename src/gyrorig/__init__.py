"""gyrorig: experiment design and data fitting for air-bearing gyroscope rigs.

Stages (each a module, passing documented pandas DataFrames along):

* ``gyrorig.protocols``: experiment files (TOML) -> validated frozen dataclasses.
* ``gyrorig.physics``: singularity-free simulator of the symmetric top / gyrostat,
  composable pivot torques, and the exact (elliptic-function) Lagrange-top solution.

Conventions (SI units, Goldstein x-convention Euler angles, gravity along -z) are
in ``docs/conventions.md``.
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
