"""Physics of the top: rotations, torques, the simulator and the exact solution.

This layer works in SI floats and imports no video, filtering or plotting library.
"""

from .exact import ExactSolutionError, LagrangeTopSolution, exact_solution, exact_solution_applies
from .simulate import METHODS, SimulationError, SimulationInfo, TRAJECTORY_COLUMNS, choose_method, simulate

__all__ = [
    "METHODS",
    "TRAJECTORY_COLUMNS",
    "SimulationError",
    "SimulationInfo",
    "choose_method",
    "simulate",
    "ExactSolutionError",
    "LagrangeTopSolution",
    "exact_solution",
    "exact_solution_applies",
]
