"""Command line: ``gyrorig <command> ...`` (thin layer over the public functions).

Exit codes: 0 success; 2 bad input (protocol, arguments); 3 a computation failed
(integration error, lost quaternion norm).  Nothing is written under a final file
name unless the whole computation succeeded.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence

from .parser import build_parser

#: exit codes: success, bad input, a failed computation
EXIT_OK, EXIT_BAD_INPUT, EXIT_FAILED = 0, 2, 3

__all__ = ["main", "build_parser", "EXIT_OK", "EXIT_BAD_INPUT", "EXIT_FAILED"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(message)s")
    # the physics and the commands are imported only now: --help and --version stay fast
    from ..physics import SimulationError
    from ..physics.exact import ExactSolutionError
    from ..protocols import ProtocolError
    from . import commands

    try:
        return int(getattr(commands, args.func)(args))
    except (ProtocolError, ExactSolutionError, ValueError) as exc:
        print(f"gyrorig: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except SimulationError as exc:
        print(f"gyrorig: simulation failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
