"""Identifying a rig from its measurements (``gyrorig identify``).

* :mod:`~gyrorig.identify.tables`: lab tables (CSV, units in the column names) read into SI;
* :mod:`~gyrorig.identify.observations`: each measurement with its exact model and the fast-top formula;
* :mod:`~gyrorig.identify.estimate`: weighted least squares with the prior protocol's priors;
* :mod:`~gyrorig.identify.configurations`: several configurations of one rig (``[[configuration]]``) sharing
  what they share;
* :mod:`~gyrorig.identify.output`: the command on files (``identified.toml``, ``identify.json``, ``identify.png``).

Estimation only: nothing here reaches the simulator (synthetic tables for its tests come from
:mod:`gyrorig.bench.identify`, which simulates).
"""

from .estimate import Identification, identify_parameters
from .observations import Observation, observations_from_fit, observations_from_table
from .output import identify_files, read_observations
from .tables import IdentifyInputError, Table, read_table, read_tables

__all__ = ["Identification", "IdentifyInputError", "Observation", "Table", "identify_files", "identify_parameters",
           "observations_from_fit", "observations_from_table", "read_observations", "read_table", "read_tables"]
