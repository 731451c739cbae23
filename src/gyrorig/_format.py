"""Numbers for people: a value printed to the digits its standard error resolves."""

from __future__ import annotations

import math

__all__ = ["with_error", "ERROR_DIGITS"]

#: significant digits of a printed standard error
ERROR_DIGITS = 2


def with_error(value: float, standard_error: float | None, *, digits: int = ERROR_DIGITS) -> str:
    """``value +- standard_error``, the error to ``digits`` significant digits and the value to the same decimal
    place (``1.71873 +- 0.000024``; a common power of ten for very large or small values:
    ``(4.7250 +- 0.0031)e-04``).  Without a usable error the value gets 6 significant digits."""
    if value is None or not math.isfinite(value):
        return str(value)
    if standard_error is None or not math.isfinite(standard_error) or standard_error <= 0:
        return f"{value:.6g}"
    last = math.floor(math.log10(standard_error)) - (digits - 1)  # the power of ten of the error's last digit
    big = max(abs(value), standard_error)
    exponent = math.floor(math.log10(big))
    if -3 <= exponent < 6:
        decimals = max(0, -last)
        return f"{round(value, -last):.{decimals}f} +- {round(standard_error, -last):.{decimals}f}"
    scale = 10.0**exponent
    decimals = max(0, exponent - last)
    return f"({value / scale:.{decimals}f} +- {standard_error / scale:.{decimals}f})e{exponent:+03d}"
