"""The fit model's terms, one class each: its parameters, its contribution, its Jacobian, when it applies.

The tip moves on a cone about an axis ``n`` (the vertical, or a fitted axis).  In the frame
whose z is ``n``, with ``tau = t - t_ref``, ``tau0`` the first frame, ``psi = w tau (+ w' tau^2 / 2
when damped)`` the nutation phase and ``E = exp(-mu (tau - tau0))`` the damped nutation's envelope,
the model is a sum of the terms below (in this order).  Each adds to the tilt ``theta'`` and the
azimuth ``phi'`` in the axis frame; the lab angles follow by rotating the cone's axis
(:class:`gyrorig.fit.model.FitModel`).  A term is written once here; the parameter vector, the
model, its Jacobian, the choice of terms and the report all read it from here.

Each term has ``present(spec)`` (in a model of that :class:`~gyrorig.fit.spec.ModelSpec`),
``names(spec)`` (its parameters), ``add(m, p, tau, segment, th, ph)`` (its contribution) and
``jacobian(m, p, tau, segment, dth, dph)`` (fills its columns, adds to shared ones).  The
optional terms (:data:`OPTIONAL`) also have ``flag`` (the spec's switch), ``can_add(spec)``, a
``label`` and a ``description`` for notes.
"""

from __future__ import annotations

import numpy as np
from scipy.special import expit

from .phases import rate_phase

__all__ = ["Term", "TERMS", "NUTATION_CURVATURE", "PRECESSION_CURVATURE", "BFrameShrink", "RollingShutter", "OPTIONAL",
           "OPTIONAL_TERMS", "MAX_HARMONICS", "SHAPE_DRIFT_NAMES", "transient_rate"]

MAX_HARMONICS = 6
#: the drifting nutation shape's two parameters (real and imaginary part of ``s``, 1/s); see :class:`ShapeDrift`
SHAPE_DRIFT_NAMES = ("shape_drift_re_per_s", "shape_drift_im_per_s")


def transient_rate(spec, logit: float) -> float:
    """The transient's decay rate, bounded smoothly between the spec's minimum and maximum. [1/s]"""
    return spec.transient_min_rate_per_s + (spec.transient_max_rate_per_s - spec.transient_min_rate_per_s) * \
        float(expit(logit))


#: a spin-down's cubic phase terms (a rate's departure from an exponential law, second order in time)
PRECESSION_CURVATURE = "precession_rate_curvature_rad_s3"
NUTATION_CURVATURE = "nutation_frequency_curvature_rad_s3"
def _pair_names(stem: str, prefixed: bool = True) -> list[str]:
    """``tilt_<stem>_cos_rad, tilt_<stem>_sin_rad, azimuth_<stem>_cos_rad, azimuth_<stem>_sin_rad`` (or
    ``<stem>_tilt_cos_rad, ...`` when not prefixed)."""
    if prefixed:
        return [f"{q}_{stem}_{f}_rad" for q in ("tilt", "azimuth") for f in ("cos", "sin")]
    return [f"{stem}_{q}_{f}_rad" for q in ("tilt", "azimuth") for f in ("cos", "sin")]


def _sinusoid_columns(m, p, tau, dth, dph, freq: str, names: list[str], factor: float = 1.0) -> None:
    """Columns of ``X_cos cos(f w tau) + X_sin sin(f w tau)`` in tilt and azimuth (``names``: the
    tilt pair, then the azimuth pair; a pair the model lacks is skipped), and their derivative with
    respect to the frequency parameter ``freq``."""
    ix = m.index
    w = factor * p[ix[freq]]
    c, sn = np.cos(w * tau), np.sin(w * tau)
    for d, (nc, ns) in ((dth, names[:2]), (dph, names[2:])):
        if nc not in ix:
            continue
        d[:, ix[nc]] = c
        d[:, ix[ns]] = sn
        d[:, ix[freq]] += factor * tau * (-p[ix[nc]] * sn + p[ix[ns]] * c)


def _nutation_phase_columns(m, p, d, ix, dpsi, tau) -> None:
    """Add a nutation term's derivative along its phase ``dpsi`` to the columns of the phase's parameters."""
    for name, column in m.nutation_phase_terms(p, tau)[1].items():
        d[:, ix[name]] += dpsi * column


class Term:
    """Base: a term present in every model, with no parameters and no contribution."""

    flag: str | None = None
    label = ""
    description = ""
    summary_key = ""
    #: a fast term (at or near the nutation frequency): a lossy codec's bi-predicted pictures show it shrunk
    #: (:class:`BFrameShrink`)
    fast = False

    def present(self, spec) -> bool:
        return True if self.flag is None else bool(getattr(spec, self.flag))

    def can_add(self, spec) -> bool:
        """Whether this optional term can be added to ``spec`` (and is not in it)."""
        return not self.present(spec)

    def names(self, spec) -> list[str]:
        return []

    def add(self, m, p, tau, segment, th, ph):
        return th, ph

    def jacobian(self, m, p, tau, segment, dth, dph) -> None:
        return None


class Axis(Term):
    """The cone's axis (``axis_tilt_rad, axis_azimuth_rad``), fitted when the pivot accelerates (the
    effective vertical) or for a free top (the angular momentum); it enters through the rotation
    from the axis frame to the lab (:meth:`gyrorig.fit.model.FitModel.lab`)."""

    def present(self, spec) -> bool:
        return spec.fit_axis

    def names(self, spec) -> list[str]:
        return ["axis_tilt_rad", "axis_azimuth_rad"]


class Slow(Term):
    """The slow motion: ``theta' = exp(c0 [+ lambda tau + c2 tau^2])``, ``phi' = phi0_s + Omega tau [+ Omegadot
    tau^2 / 2]``; the bracketed parts only under damping; one azimuth offset per segment (a gap longer
    than half a precession period splits the record: the turns in it are not seen)."""

    def names(self, spec) -> list[str]:
        n = ["log_cone_angle", "precession_rate_rad_s"]
        if spec.damped:
            n += ["tilt_growth_rate_per_s", "tilt_growth_curvature_per_s2", "precession_acceleration_rad_s2"]
        if spec.spin_decay:
            n += [PRECESSION_CURVATURE]
        return n + [f"azimuth_offset_{s}_rad" for s in range(spec.segments)]

    @staticmethod
    def _log_tilt(m, p, tau):
        ix = m.index
        slow = p[ix["log_cone_angle"]]
        if m.spec.damped:
            slow = slow + p[ix["tilt_growth_rate_per_s"]] * tau + p[ix["tilt_growth_curvature_per_s2"]] * tau**2
        return np.exp(slow) * np.ones_like(tau)

    def add(self, m, p, tau, segment, th, ph):
        ix, s = m.index, m.spec
        th = th + self._log_tilt(m, p, tau)
        offsets = p[[ix[f"azimuth_offset_{k}_rad"] for k in range(s.segments)]]
        change = p[ix["precession_acceleration_rad_s2"]] if s.damped else 0.0
        phase, _, _ = rate_phase(p[ix["precession_rate_rad_s"]], change, tau, s.spin_decay)
        if s.spin_decay:
            phase = phase + p[ix[PRECESSION_CURVATURE]] * tau**3 / 3
        return th, ph + offsets[segment] + phase

    def jacobian(self, m, p, tau, segment, dth, dph) -> None:
        ix, s = m.index, m.spec
        e = self._log_tilt(m, p, tau)
        dth[:, ix["log_cone_angle"]] = e
        change = p[ix["precession_acceleration_rad_s2"]] if s.damped else 0.0
        _, d_rate, d_change = rate_phase(p[ix["precession_rate_rad_s"]], change, tau, s.spin_decay)
        dph[:, ix["precession_rate_rad_s"]] = d_rate
        for k in range(s.segments):
            dph[:, ix[f"azimuth_offset_{k}_rad"]] = segment == k
        if s.damped:
            dth[:, ix["tilt_growth_rate_per_s"]] = tau * e
            dth[:, ix["tilt_growth_curvature_per_s2"]] = tau**2 * e
            dph[:, ix["precession_acceleration_rad_s2"]] = d_change
        if s.spin_decay:
            dph[:, ix[PRECESSION_CURVATURE]] = tau**3 / 3


class Nutation(Term):
    """The nutation: ``E^k (a_k cos k psi + b_k sin k psi)`` in the tilt and ``E^k (c_k cos k psi + d_k sin
    k psi)`` in the azimuth, ``k = 1 .. harmonics`` (harmonic k of a decaying oscillation decays k times
    as fast); under damping also offsets decaying as ``E^2`` in both angles (second order in the
    amplitude: the mean tilt and precession rate shift with amplitude^2).  Undamped, ``E = 1`` and the
    model is exact given enough harmonics (a heavy top's tilt is periodic, and ``phi - Omega t`` too)."""

    fast = True

    def present(self, spec) -> bool:
        return spec.harmonics > 0

    def names(self, spec) -> list[str]:
        n = ["nutation_frequency_rad_s"]
        if spec.damped:
            n += ["nutation_decay_rate_per_s", "nutation_chirp_rad_s2", "tilt_decaying_offset_rad"]
            if spec.spin_decay:
                n += [NUTATION_CURVATURE]
            if not spec.spin_decay:  # a spin decaying: the precession's own exponential change holds it
                n += ["azimuth_decaying_offset_rad"]
        for k in range(1, spec.harmonics + 1):
            n += [f"tilt_cos_{k}_rad", f"tilt_sin_{k}_rad", f"azimuth_cos_{k}_rad", f"azimuth_sin_{k}_rad"]
        return n

    def add(self, m, p, tau, segment, th, ph):
        ix, s = m.index, m.spec
        env1 = m.envelope(p, tau) if s.damped else np.ones_like(tau)
        if s.damped:
            env2 = env1 * env1
            th = th + p[ix["tilt_decaying_offset_rad"]] * env2
            if not s.spin_decay:
                ph = ph + p[ix["azimuth_decaying_offset_rad"]] * env2
        env = env1
        psi = m.nutation_phase(p, tau)
        for k in range(1, s.harmonics + 1):
            c, sn = np.cos(k * psi), np.sin(k * psi)
            th = th + env * (p[ix[f"tilt_cos_{k}_rad"]] * c + p[ix[f"tilt_sin_{k}_rad"]] * sn)
            ph = ph + env * (p[ix[f"azimuth_cos_{k}_rad"]] * c + p[ix[f"azimuth_sin_{k}_rad"]] * sn)
            if s.damped:
                env = env * env1
        return th, ph

    def jacobian(self, m, p, tau, segment, dth, dph) -> None:
        ix, s = m.index, m.spec
        dt0 = tau - s.nutation_origin_s
        env1 = m.envelope(p, tau) if s.damped else np.ones_like(tau)
        psi = m.nutation_phase(p, tau)
        if s.damped:
            env2 = env1 * env1
            a0 = p[ix["tilt_decaying_offset_rad"]]
            c0 = 0.0 if s.spin_decay else p[ix["azimuth_decaying_offset_rad"]]
            dth[:, ix["tilt_decaying_offset_rad"]] = env2
            if not s.spin_decay:
                dph[:, ix["azimuth_decaying_offset_rad"]] = env2
            dth[:, ix["nutation_decay_rate_per_s"]] += -2 * dt0 * env2 * a0
            dph[:, ix["nutation_decay_rate_per_s"]] += -2 * dt0 * env2 * c0
        env = env1
        for k in range(1, s.harmonics + 1):
            c, sn = np.cos(k * psi), np.sin(k * psi)
            a, b = p[ix[f"tilt_cos_{k}_rad"]], p[ix[f"tilt_sin_{k}_rad"]]
            cc, dd = p[ix[f"azimuth_cos_{k}_rad"]], p[ix[f"azimuth_sin_{k}_rad"]]
            dth[:, ix[f"tilt_cos_{k}_rad"]] = env * c
            dth[:, ix[f"tilt_sin_{k}_rad"]] = env * sn
            dph[:, ix[f"azimuth_cos_{k}_rad"]] = env * c
            dph[:, ix[f"azimuth_sin_{k}_rad"]] = env * sn
            dpsi_t = env * k * (-a * sn + b * c)  # d/d psi of the tilt term
            dpsi_p = env * k * (-cc * sn + dd * c)
            _nutation_phase_columns(m, p, dth, ix, dpsi_t, tau)
            _nutation_phase_columns(m, p, dph, ix, dpsi_p, tau)
            if s.damped:
                dth[:, ix["nutation_decay_rate_per_s"]] += -k * dt0 * env * (a * c + b * sn)
                dph[:, ix["nutation_decay_rate_per_s"]] += -k * dt0 * env * (cc * c + dd * sn)
                env = env * env1


class PrecessionLocked(Term):
    """Damping about the lab vertical while the cone's axis is tilted (damped, fitted axis) makes the cone
    uneven: ``e cos(Omega tau) + f sin(Omega tau)`` in the azimuth only (in the tilt such a term is, to
    first order, a shift of the fitted axis, and made the fit two-valued)."""

    NAMES = ["azimuth_precession_cos_rad", "azimuth_precession_sin_rad"]

    def present(self, spec) -> bool:
        return spec.damped and spec.fit_axis

    def names(self, spec) -> list[str]:
        return list(self.NAMES)

    def add(self, m, p, tau, segment, th, ph):
        ix = m.index
        cp, sp = np.cos(p[ix["precession_rate_rad_s"]] * tau), np.sin(p[ix["precession_rate_rad_s"]] * tau)
        return th, ph + p[ix["azimuth_precession_cos_rad"]] * cp + p[ix["azimuth_precession_sin_rad"]] * sp

    def jacobian(self, m, p, tau, segment, dth, dph) -> None:
        _sinusoid_columns(m, p, tau, dth, dph, "precession_rate_rad_s", ["", ""] + self.NAMES)


class Persistent(Term):
    """An undamped oscillation near the nutation frequency, its frequency free:
    ``A cos(w_p tau) + B sin(w_p tau)`` in both angles (under damping the drifting slow mode can keep
    one alive)."""

    fast = True

    flag = "persistent"
    label = "persistent oscillation"
    description = "a persistent oscillation near the nutation frequency"
    summary_key = "persistent_oscillation"
    AMPLITUDES = tuple(_pair_names("persistent", prefixed=False))

    def can_add(self, spec) -> bool:
        return not spec.persistent and spec.harmonics > 0

    def names(self, spec) -> list[str]:
        return ["persistent_frequency_rad_s", *self.AMPLITUDES]

    def add(self, m, p, tau, segment, th, ph):
        ix = m.index
        wp = p[ix["persistent_frequency_rad_s"]]
        c, sn = np.cos(wp * tau), np.sin(wp * tau)
        th = th + p[ix["persistent_tilt_cos_rad"]] * c + p[ix["persistent_tilt_sin_rad"]] * sn
        ph = ph + p[ix["persistent_azimuth_cos_rad"]] * c + p[ix["persistent_azimuth_sin_rad"]] * sn
        return th, ph

    def jacobian(self, m, p, tau, segment, dth, dph) -> None:
        _sinusoid_columns(m, p, tau, dth, dph, "persistent_frequency_rad_s", list(self.AMPLITUDES))


class Transient(Term):
    """A fast exponential transient from the first frame, ``b exp(-kappa (tau - tau0))`` in both angles
    (after release a damped gyrostat's frame spin relaxes in ``I_frame / c``, tens of ms); ``kappa`` is
    bounded smoothly between the spec's minimum and maximum through ``transient_rate_logit``."""

    fast = True

    flag = "transient"
    label = "transient"
    description = "a fast transient from the first frame"
    summary_key = "transient"
    AMPLITUDES = ("transient_tilt_rad", "transient_azimuth_rad")

    def names(self, spec) -> list[str]:
        return ["transient_rate_logit", *self.AMPLITUDES]

    def add(self, m, p, tau, segment, th, ph):
        ix, s = m.index, m.spec
        e = np.exp(-transient_rate(s, p[ix["transient_rate_logit"]]) * (tau - s.nutation_origin_s))
        return th + p[ix["transient_tilt_rad"]] * e, ph + p[ix["transient_azimuth_rad"]] * e

    def jacobian(self, m, p, tau, segment, dth, dph) -> None:
        ix, s = m.index, m.spec
        u = p[ix["transient_rate_logit"]]
        dt0 = tau - s.nutation_origin_s
        e = np.exp(-transient_rate(s, u) * dt0)
        sg = expit(u)
        dk = (s.transient_max_rate_per_s - s.transient_min_rate_per_s) * sg * (1 - sg)
        dth[:, ix["transient_tilt_rad"]] = e
        dph[:, ix["transient_azimuth_rad"]] = e
        dth[:, ix["transient_rate_logit"]] = -dk * dt0 * e * p[ix["transient_tilt_rad"]]
        dph[:, ix["transient_rate_logit"]] = -dk * dt0 * e * p[ix["transient_azimuth_rad"]]


class Sidebands(Term):
    """Nutation sidebands at ``psi +- Omega tau`` with the envelope ``E`` (damped, fitted axis: damping
    about the lab vertical modulates the nutation with the precession phase)."""

    fast = True

    flag = "sidebands"
    label = "nutation sidebands"
    description = ("nutation sidebands at the nutation frequency +- the precession rate (damping about the lab "
                   "vertical modulates the nutation)")
    summary_key = "nutation_sidebands"
    SIDES = (("upper", 1.0), ("lower", -1.0))

    def can_add(self, spec) -> bool:
        return not spec.sidebands and spec.fit_axis and spec.harmonics > 0

    def names(self, spec) -> list[str]:
        return [n for side, _ in self.SIDES for n in _pair_names(side)]

    def add(self, m, p, tau, segment, th, ph):
        ix = m.index
        psi = m.nutation_phase(p, tau)
        env1 = m.envelope(p, tau)
        for side, sign in self.SIDES:
            arg = psi + sign * p[ix["precession_rate_rad_s"]] * tau
            c, sn = env1 * np.cos(arg), env1 * np.sin(arg)
            th = th + p[ix[f"tilt_{side}_cos_rad"]] * c + p[ix[f"tilt_{side}_sin_rad"]] * sn
            ph = ph + p[ix[f"azimuth_{side}_cos_rad"]] * c + p[ix[f"azimuth_{side}_sin_rad"]] * sn
        return th, ph

    def jacobian(self, m, p, tau, segment, dth, dph) -> None:
        ix = m.index
        psi = m.nutation_phase(p, tau)
        dt0 = tau - m.spec.nutation_origin_s
        env1 = m.envelope(p, tau)
        for side, sign in self.SIDES:
            arg = psi + sign * p[ix["precession_rate_rad_s"]] * tau
            c, sn = env1 * np.cos(arg), env1 * np.sin(arg)
            for d, q in ((dth, "tilt"), (dph, "azimuth")):
                a, b = p[ix[f"{q}_{side}_cos_rad"]], p[ix[f"{q}_{side}_sin_rad"]]
                d[:, ix[f"{q}_{side}_cos_rad"]] = c
                d[:, ix[f"{q}_{side}_sin_rad"]] = sn
                darg = -a * sn + b * c  # d/d arg
                _nutation_phase_columns(m, p, d, ix, darg, tau)
                d[:, ix["precession_rate_rad_s"]] += darg * sign * tau
                d[:, ix["nutation_decay_rate_per_s"]] += -dt0 * (a * c + b * sn)


class ShapeDrift(Term):
    """The damped nutation's shape drifts: the ratio and phase of its tilt and azimuth parts change
    linearly in time (the mode shape depends on the tilt, which drifts; first order, like the chirp).

    With the fundamental as complex amplitudes ``z_t = a - i b`` (tilt) and ``z_p = c - i d``
    (azimuth), the term is ``(tau - tau0) E Re[u e^{i psi}]`` with ``(u_t, u_p) = s (-conj(z_p),
    conj(z_t))``, ``s`` complex (:data:`SHAPE_DRIFT_NAMES`): the complex direction orthogonal to
    ``(z_t, z_p)``.  A drift along ``(z_t, z_p)`` itself is, to first order, a change of the decay
    rate (real ``s``) or of the nutation frequency (imaginary ``s``): with four free coefficients those
    two would be fixed only by the weak higher-order terms, and the fit would not be linear over one
    standard error."""

    fast = True

    flag = "shape_drift"
    label = "drifting nutation shape"
    description = "a drifting nutation shape (its tilt and azimuth parts change linearly in time as the tilt drifts)"
    summary_key = "nutation_shape_drift"
    FUNDAMENTAL = ["tilt_cos_1_rad", "tilt_sin_1_rad", "azimuth_cos_1_rad", "azimuth_sin_1_rad"]

    def can_add(self, spec) -> bool:
        return not spec.shape_drift and spec.harmonics > 0

    def names(self, spec) -> list[str]:
        return list(SHAPE_DRIFT_NAMES)

    def coefficients(self, m, p):
        """The coefficients of ``f cos psi, f sin psi`` in tilt and azimuth ``(A_t, B_t, A_p, B_p)``, and
        their derivatives (4 x 6) with respect to ``s`` and the fundamental's amplitudes."""
        ix = m.index
        sr, si = (p[ix[n]] for n in SHAPE_DRIFT_NAMES)
        a, b, c, d = (p[ix[n]] for n in self.FUNDAMENTAL)
        # u_t = -s conj(z_p), u_p = s conj(z_t); a term Re[u e^{i psi}] = Re(u) cos psi - Im(u) sin psi
        coef = (-(sr * c - si * d), sr * d + si * c, sr * a - si * b, -(sr * b + si * a))
        #              d/d sr, si,  a,   b,   c,   d
        dcoef = np.array([[-c, d, 0.0, 0.0, -sr, si],
                          [d, c, 0.0, 0.0, si, sr],
                          [a, -b, sr, -si, 0.0, 0.0],
                          [-b, -a, -si, -sr, 0.0, 0.0]])
        return coef, (list(SHAPE_DRIFT_NAMES) + self.FUNDAMENTAL, dcoef)

    def add(self, m, p, tau, segment, th, ph):
        f = (tau - m.spec.nutation_origin_s) * m.envelope(p, tau)
        psi = m.nutation_phase(p, tau)
        (at, bt, ap, bp), _ = self.coefficients(m, p)
        c, sn = f * np.cos(psi), f * np.sin(psi)
        return th + at * c + bt * sn, ph + ap * c + bp * sn

    def jacobian(self, m, p, tau, segment, dth, dph) -> None:
        ix = m.index
        dt0 = tau - m.spec.nutation_origin_s
        f = dt0 * m.envelope(p, tau)
        psi = m.nutation_phase(p, tau)
        c, sn = f * np.cos(psi), f * np.sin(psi)
        (at, bt, ap, bp), (names, dcoef) = self.coefficients(m, p)
        for j, name in enumerate(names):
            dth[:, ix[name]] += dcoef[0, j] * c + dcoef[1, j] * sn
            dph[:, ix[name]] += dcoef[2, j] * c + dcoef[3, j] * sn
        for d, a, b in ((dth, at, bt), (dph, ap, bp)):
            dpsi = -a * sn + b * c
            _nutation_phase_columns(m, p, d, ix, dpsi, tau)
            d[:, ix["nutation_decay_rate_per_s"]] += -dt0 * (a * c + b * sn)


class ThirdOrder(Term):
    """Third order in the damped nutation's amplitude: ``E^3 (cos psi, sin psi)`` with four free
    coefficients (the nutation's shape depends on its amplitude, which decays)."""

    fast = True

    flag = "third_order"
    label = "third-order nutation"
    description = "a third-order nutation term decaying three times as fast (the nutation's shape changes with its " \
                  "amplitude)"
    summary_key = "third_order_nutation"
    NAMES = _pair_names("third")

    def can_add(self, spec) -> bool:
        return not spec.third_order and spec.harmonics > 0

    def names(self, spec) -> list[str]:
        return list(self.NAMES)

    def add(self, m, p, tau, segment, th, ph):
        ix = m.index
        env1, psi = m.envelope(p, tau), m.nutation_phase(p, tau)
        f = np.ones_like(tau) * env1**3
        c, sn = f * np.cos(psi), f * np.sin(psi)
        th = th + p[ix["tilt_third_cos_rad"]] * c + p[ix["tilt_third_sin_rad"]] * sn
        ph = ph + p[ix["azimuth_third_cos_rad"]] * c + p[ix["azimuth_third_sin_rad"]] * sn
        return th, ph

    def jacobian(self, m, p, tau, segment, dth, dph) -> None:
        ix = m.index
        dt0 = tau - m.spec.nutation_origin_s
        env1, psi = m.envelope(p, tau), m.nutation_phase(p, tau)
        f = np.ones_like(tau) * env1**3
        c, sn = f * np.cos(psi), f * np.sin(psi)
        for d, q in ((dth, "tilt"), (dph, "azimuth")):
            nc, ns = f"{q}_third_cos_rad", f"{q}_third_sin_rad"
            a, b = p[ix[nc]], p[ix[ns]]
            d[:, ix[nc]] = c
            d[:, ix[ns]] = sn
            dpsi = -a * sn + b * c
            _nutation_phase_columns(m, p, d, ix, dpsi, tau)
            d[:, ix["nutation_decay_rate_per_s"]] += -3 * dt0 * (a * c + b * sn)


class PrecessionSecond(Term):
    """The second harmonic of the precession phase in both angles: an elliptical cone (damped, fitted axis)."""

    flag = "precession_second"
    label = "elliptical cone"
    description = "a second harmonic of the precession (an elliptical cone)"
    summary_key = "elliptical_cone"
    NAMES = _pair_names("precession2")

    def can_add(self, spec) -> bool:
        return not spec.precession_second and spec.fit_axis

    def names(self, spec) -> list[str]:
        return list(self.NAMES)

    def add(self, m, p, tau, segment, th, ph):
        ix = m.index
        c2, s2 = np.cos(2 * p[ix["precession_rate_rad_s"]] * tau), np.sin(2 * p[ix["precession_rate_rad_s"]] * tau)
        th = th + p[ix["tilt_precession2_cos_rad"]] * c2 + p[ix["tilt_precession2_sin_rad"]] * s2
        ph = ph + p[ix["azimuth_precession2_cos_rad"]] * c2 + p[ix["azimuth_precession2_sin_rad"]] * s2
        return th, ph

    def jacobian(self, m, p, tau, segment, dth, dph) -> None:
        _sinusoid_columns(m, p, tau, dth, dph, "precession_rate_rad_s", list(self.NAMES), factor=2.0)


class TipOffset(Term):
    """A tip marker off the stem's axis, on a gyrostat's frame: at ``(A, B)`` (its offset over its distance from the
    pivot) in the frame's coordinates, the frame turning about the axis at its own rate ``w_f`` (``psi_f = w_f tau``;
    its spin less the precession's share along the axis, ``-phi' cos(theta)`` averaged over the nod: fitted, started
    from ``-Omega cos(theta_c)``): off the axis by ``-(A sin psi_f + B cos psi_f)`` in the tilt, ``(A cos psi_f - B sin
    psi_f) / sin(theta_c)`` in the azimuth."""

    flag = "tip_offset"
    label = "tip marker off the axis"
    description = "a tip marker off the stem's axis, turning with the frame"
    summary_key = "tip_offset"
    NAMES = ("tip_offset_a_rad", "tip_offset_b_rad")
    RATE = "frame_turn_rate_rad_s"

    def can_add(self, spec) -> bool:
        return spec.gyrostat and not spec.tip_offset

    def names(self, spec) -> list[str]:
        return [*self.NAMES, self.RATE]

    def add(self, m, p, tau, segment, th, ph):
        ix = m.index
        psi = p[ix[self.RATE]] * tau
        a, b = p[ix["tip_offset_a_rad"]], p[ix["tip_offset_b_rad"]]
        c, sn = np.cos(psi), np.sin(psi)
        return th - (a * sn + b * c), ph + (a * c - b * sn) / max(np.sin(np.exp(p[ix["log_cone_angle"]])), 1e-12)

    def jacobian(self, m, p, tau, segment, dth, dph) -> None:
        ix = m.index
        psi = p[ix[self.RATE]] * tau
        cone = np.exp(p[ix["log_cone_angle"]])
        a, b = p[ix["tip_offset_a_rad"]], p[ix["tip_offset_b_rad"]]
        c, sn, sin_cone = np.cos(psi), np.sin(psi), max(np.sin(cone), 1e-12)
        dth[:, ix["tip_offset_a_rad"]] = -sn
        dth[:, ix["tip_offset_b_rad"]] = -c
        dph[:, ix["tip_offset_a_rad"]] = c / sin_cone
        dph[:, ix["tip_offset_b_rad"]] = -sn / sin_cone
        dth[:, ix[self.RATE]] = -(a * c - b * sn) * tau
        dph[:, ix[self.RATE]] = -(a * sn + b * c) * tau / sin_cone
        dph[:, ix["log_cone_angle"]] += -(a * c - b * sn) * np.cos(cone) / sin_cone**2 * cone


class BFrameShrink(Term):
    """A lossy codec's bi-predicted pictures (``frame_type`` B) show the fast motion shrunk: such a picture is, where
    the codec left out its residual, a blend of its reference pictures, and the blend averages the spot's
    positions over neighbouring frames (measured on HEVC renders: 1.5 % at 59.5 rad/s and 200 fps, none without B
    pictures).  The fast terms (``fast``) of those frames are multiplied by ``1 - b_frame_shrink``; the others
    (I and P pictures) pin the true amplitude.  Applied by :class:`gyrorig.fit.model.FitModel` from the data's
    rows; present when the record has both kinds of picture and a nutation."""

    NAME = "b_frame_shrink"

    def present(self, spec) -> bool:
        return spec.b_frames and spec.harmonics > 0

    def names(self, spec) -> list[str]:
        return [self.NAME]


class RollingShutter(Term):
    """A rolling shutter whose readout time camera.json does not state (a phone's: 4-30 ms): each row of a frame is
    read later than the one above, so a tip at the row fraction ``y / height`` was seen ``readout_time_s`` times
    that after the frame's time.  Left out, the delay follows the tip's row, which the precession and the nod move:
    the record's clock is warped, and the rates are biased with a chi-square that can look right (measured in
    docs/recordings.md).  The model is evaluated at ``tau + row_fraction * readout_time_s`` (:class:`gyrorig.fit.model.Residuals`, from the data's rows); present when the angle table
    gives each frame's row."""

    NAME = "readout_time_s"

    def present(self, spec) -> bool:
        return spec.rolling_shutter

    def names(self, spec) -> list[str]:
        return [self.NAME]


class CameraModes(Term):
    """Nuisance parameters for the camera model's uncertainty, one per mode (``a_k``), each with a unit
    Gaussian prior: the model adds ``sum_k a_k (theta_cam_k, phi_cam_k)`` in the lab (see
    :class:`gyrorig.fit.model.Residuals`).  Always last in the parameter vector."""

    def present(self, spec) -> bool:
        return spec.camera_modes > 0

    def names(self, spec) -> list[str]:
        return [f"camera_mode_{k + 1}" for k in range(spec.camera_modes)]


#: the terms in the order of the parameter vector and of evaluation
TERMS: tuple[Term, ...] = (Axis(), Slow(), Nutation(), PrecessionLocked(), Persistent(), Transient(), Sidebands(),
                           ShapeDrift(), ThirdOrder(), PrecessionSecond(), TipOffset(), BFrameShrink(),
                           RollingShutter(), CameraModes())
#: the optional terms of a damped model, in the order they are tried (the nutation's own slow changes
#: first: the later terms could otherwise stand in for them)
OPTIONAL: dict[str, Term] = {t.flag: t for t in sorted((t for t in TERMS if t.flag),
                                                       key=lambda t: ("shape_drift", "third_order", "persistent",
                                                                      "transient", "precession_second",
                                                                      "sidebands", "tip_offset").index(t.flag))}
OPTIONAL_TERMS = tuple(OPTIONAL)
