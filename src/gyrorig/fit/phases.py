"""The phase of a rate that changes in time: linear, or exponential (a rate proportional to a decaying spin or to its
inverse), for the fit model's precession and nutation (:mod:`gyrorig.fit.terms`)."""

from __future__ import annotations

import numpy as np

__all__ = ["rate_phase"]

#: |a tau| below which :func:`rate_phase` sums its series (the closed form loses digits to cancellation there)
_SERIES_LIMIT = 1e-3
#: |a tau| beyond which :func:`rate_phase` holds the exponential (a start far off: no overflow)
_EXP_LIMIT = 50.0


def rate_phase(rate: float, change: float, tau: np.ndarray, exponential: bool
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The phase ``int_0^tau w(t) dt`` of a rate ``w`` that is ``rate`` at ``tau = 0`` and changes there at ``change``
    per second, and its derivatives with respect to ``rate`` and ``change``: ``w`` linear in time (``rate tau +
    change tau^2 / 2``), or with ``exponential`` (a rate proportional to a decaying spin or to its inverse) ``w =
    rate exp(a t)``, ``a = change / rate``: the phase ``rate (exp(a tau) - 1) / a``."""
    if not exponential or rate == 0.0:
        return rate * tau + 0.5 * change * tau**2, tau, 0.5 * tau**2
    a = change / rate
    x = np.clip(a * tau, -_EXP_LIMIT, _EXP_LIMIT)
    series = np.abs(x) < _SERIES_LIMIT
    safe_a = a if a != 0.0 else 1.0
    f = np.where(series, tau * (1.0 + x / 2 + x * x / 6 + x**3 / 24), np.expm1(x) / safe_a)
    f_a = np.where(series, tau**2 * (0.5 + x / 3 + x * x / 8), (tau * np.exp(x) - f) / safe_a)
    return rate * f, f - a * f_a, f_a
