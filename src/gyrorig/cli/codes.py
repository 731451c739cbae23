"""The command line's exit codes (apart from :mod:`gyrorig.cli`, which runs the commands that return them)."""

#: success, bad input, a failed computation, interrupted (Ctrl-C; SIGTERM and SIGHUP exit 128 + the signal)
EXIT_OK, EXIT_BAD_INPUT, EXIT_FAILED, EXIT_INTERRUPTED = 0, 2, 3, 130

__all__ = ["EXIT_OK", "EXIT_BAD_INPUT", "EXIT_FAILED", "EXIT_INTERRUPTED"]
