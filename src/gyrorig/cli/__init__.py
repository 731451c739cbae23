"""Command line: ``gyrorig <command> ...`` (thin layer over the public functions).

Exit codes: 0 success; 2 bad input (protocol, arguments, a file that cannot be read or
written); 3 a computation failed (integration error, lost quaternion norm, or an unexpected
error: one line, the traceback only with ``--debug``); 130 interrupted (Ctrl-C).  Nothing is written under a final file
name unless the whole computation succeeded.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence

from .parser import build_parser

#: exit codes: success, bad input, a failed computation, interrupted (Ctrl-C)
EXIT_OK, EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERRUPTED = 0, 2, 3, 130

__all__ = ["main", "build_parser", "EXIT_OK", "EXIT_BAD_INPUT", "EXIT_FAILED", "EXIT_INTERRUPTED"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(message)s")
    # the physics and the commands are imported only now: --help and --version stay fast
    from ..physics import SimulationError
    from ..physics.exact import ExactSolutionError
    from ..protocols import ProtocolError
    from ..tracking.errors import TrackingError
    from . import commands

    try:
        return int(getattr(commands, args.func)(args))
    except (ProtocolError, ExactSolutionError, ValueError) as exc:  # includes tracking's BadInputError
        print(f"gyrorig: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except TrackingError as exc:
        print(f"gyrorig: tracking failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except SimulationError as exc:
        print(f"gyrorig: simulation failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print("gyrorig: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except OSError as exc:  # a file or folder that cannot be written or read
        if args.debug:
            raise
        print(f"gyrorig: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": "), file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:  # noqa: BLE001 - the last net: one line, never a traceback (unless --debug)
        if args.debug:
            raise
        print(f"gyrorig: failed: {type(exc).__name__}: {exc} (run with --debug for the traceback)", file=sys.stderr)
        return EXIT_FAILED
