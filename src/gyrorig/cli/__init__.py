"""Command line: ``gyrorig <command> ...`` (thin layer over the public functions).

Exit codes: 0 success; 2 bad input (protocol, arguments, a file that cannot be read or
written); 3 a computation failed (integration error, lost quaternion norm, or an unexpected
error: one line, the traceback only with ``--debug``); 130 interrupted (Ctrl-C).  Nothing is written under a final file
name unless the whole computation succeeded: ``--out`` is written as a temporary folder and renamed into place
(an existing non-empty one is refused unless ``--overwrite``).
"""

from __future__ import annotations

import contextlib
import io
import logging
import re
import sys
import threading
from collections.abc import Sequence
from pathlib import Path

from .codes import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK
from .parser import build_parser

__all__ = ["main", "build_parser", "EXIT_OK", "EXIT_BAD_INPUT", "EXIT_FAILED", "EXIT_INTERRUPTED"]


def _announce_compiling() -> None:
    """Say so (once, on stderr) when a compiled kernel is not in numba's disk cache and is being compiled:
    the first run after an install or an upgrade spends seconds there, later runs load it."""
    from numba.core import event

    class Notice(event.Listener):
        said = False

        def on_start(self, ev):
            disp = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
            module = getattr(getattr(disp, "py_func", None), "__module__", "") or ""
            if not Notice.said and module.startswith("gyrorig"):
                Notice.said = True
                print("gyrorig: compiling the numerical kernels (once after an install or an upgrade; cached on "
                      "disk for later runs) ...", file=sys.stderr, flush=True)

        def on_end(self, ev):
            pass

    if not getattr(_announce_compiling, "registered", False):
        event.register("numba:compile", Notice())
        _announce_compiling.registered = True


class _Renaming(io.TextIOBase):
    """A text stream that names the final output folder where the command wrote its temporary one."""

    def __init__(self, stream, tmp: str, final: str):
        self.stream, self.tmp, self.final = stream, tmp, final

    def write(self, text: str) -> int:
        return self.stream.write(text.replace(self.tmp, self.final))

    def flush(self) -> None:
        self.stream.flush()

    def isatty(self) -> bool:
        return self.stream.isatty()


@contextlib.contextmanager
def _output(args):
    """The command writes into a fresh temporary folder beside ``--out``, renamed into place when complete
    (``--overwrite``: replacing an existing one whole); a single output file (``calibrate``) is refused
    when it exists, unless ``--overwrite``."""
    from .. import _io

    out = getattr(args, "out", None)
    if out is None or not hasattr(args, "overwrite"):
        yield
        return
    if getattr(args, "out_is_file", False):
        if Path(out).exists() and not args.overwrite:
            raise _io.OutputExistsError(f"{out}: exists; give another --out, or --overwrite to replace it")
        yield
        return
    inputs = [v for k, v in vars(args).items() if k != "out" and isinstance(v, str) and v and Path(v).exists()]
    inputs += [x for k, v in vars(args).items() if isinstance(v, list) for x in v
               if isinstance(x, str) and Path(x).exists()]
    with _io.output_folder(out, args.overwrite, keep=tuple(inputs)) as tmp:
        final = str(Path(out).absolute())
        args.out = str(tmp)
        with contextlib.redirect_stdout(_Renaming(sys.stdout, str(tmp), final)), \
                contextlib.redirect_stderr(_Renaming(sys.stderr, str(tmp), final)):
            yield


def _interruption(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt (Ctrl-C, or :class:`Terminated`) in the exception's chain (its cause or context)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def _show_first_look(exc, out) -> str | None:
    """For a tip never found: the first frame searched with its spots and verdicts, written beside ``--out``
    (``OUT.first-look.png``; the output folder itself is not made for a failed run); its path, or None."""
    look = getattr(exc, "first_look", None)
    if look is None or out is None:
        return None
    from ..report.overlay import write_first_look

    path = Path(out).absolute()
    path = path.with_name(path.name + ".first-look.png")
    try:
        return str(write_first_look(look, path))
    except OSError:
        return None


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP: unwound like Ctrl-C (temporary folders removed, earlier outputs kept)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _terminate(signum, frame) -> None:
    raise Terminated(signum)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (128 + the signal's number for SIGTERM and SIGHUP)."""
    import signal

    handled = [s for s in (getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None)) if s is not None]
    before = {}
    if threading.current_thread() is threading.main_thread():
        before = {s: signal.signal(s, _terminate) for s in handled}
    try:
        return _main(argv)
    except KeyboardInterrupt as exc:  # anywhere: while the modules load, in a command, or inside compiled code
        signum = exc.signum if isinstance(exc, Terminated) else None
        print("gyrorig: interrupted" if signum is None else f"gyrorig: terminated (signal {signum})", file=sys.stderr)
        return EXIT_INTERRUPTED if signum is None else 128 + signum
    finally:
        for s, h in before.items():
            signal.signal(s, h)


#: options whose value is a comma-separated list of numbers (argparse takes "-80,50,-50" for an option)
_NUMBER_LIST_OPTIONS = ("--board-origin-mm", "--azimuth-mark-px", "--mark-position-mm")
_NUMBER_LIST = re.compile(r"^-[0-9.]+(,[-+0-9.eE]+)*$")


def _join_number_lists(argv: list[str]) -> list[str]:
    """``--board-origin-mm -80,50,-50`` as ``--board-origin-mm=-80,50,-50`` (and the other number lists)."""
    out: list[str] = []
    for token in argv:
        if out and out[-1] in _NUMBER_LIST_OPTIONS and _NUMBER_LIST.match(token):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(_join_number_lists(list(sys.argv[1:] if argv is None else argv)))
    level = logging.INFO if args.verbose else logging.ERROR if args.quiet else logging.WARNING
    logging.basicConfig(level=level, format="%(levelname)s %(message)s")
    # the physics and the commands are imported only now: --help and --version stay fast
    from ..physics import SimulationError
    from ..physics.exact import ExactSolutionError
    from ..protocols import ProtocolError
    from ..tracking.errors import TrackingError
    from . import commands
    from .printing import set_quiet

    set_quiet(sys.stdout if args.quiet else None)
    if not args.quiet:
        _announce_compiling()
    quiet = contextlib.redirect_stdout(io.StringIO()) if args.quiet else contextlib.nullcontext()
    final_out = getattr(args, "out", None)
    try:
        with quiet, _output(args):
            return int(getattr(commands, args.func)(args))
    except (ProtocolError, ExactSolutionError, ValueError) as exc:  # includes tracking's BadInputError
        if args.debug:
            raise
        # a ValueError that is a failed computation says so; numpy's LinAlgError (a singular matrix) is one that no
        # input check foresaw
        from numpy.linalg import LinAlgError

        unforeseen = isinstance(exc, LinAlgError)
        code = getattr(exc, "exit_code", EXIT_FAILED if unforeseen else EXIT_BAD_INPUT)
        print(f"gyrorig: {'error' if code == EXIT_BAD_INPUT else 'failed'}: {exc}"
              + (" (run with --debug for the traceback)" if unforeseen else ""), file=sys.stderr)
        return code
    except TrackingError as exc:
        shown = _show_first_look(exc, final_out)
        print(f"gyrorig: tracking failed: {exc}" + (f"; each spot and why it was refused: {shown}" if shown else ""),
              file=sys.stderr)
        return EXIT_FAILED
    except SimulationError as exc:
        print(f"gyrorig: simulation failed: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except RecursionError:  # the parsers (TOML, JSON) recurse per level of nesting
        print("gyrorig: error: an input file is nested too deeply to read (arrays or tables inside each other "
              "thousands of levels deep)", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:  # a file or folder that cannot be written or read
        if args.debug:
            raise
        print(f"gyrorig: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": "), file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:  # noqa: BLE001 - the last net: one line, never a traceback (unless --debug)
        interruption = _interruption(exc)
        if interruption is not None:  # Ctrl-C inside compiled code comes back as a SystemError around it
            raise interruption from None
        if args.debug:
            raise
        one_line = " ".join(str(exc).split())  # OpenCV's messages span lines
        print(f"gyrorig: failed: {type(exc).__name__}: {one_line} (run with --debug for the traceback)", file=sys.stderr)
        return EXIT_FAILED
