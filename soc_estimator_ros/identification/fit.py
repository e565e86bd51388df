"""Fits of one pulse test: OCV points, the 2-RC Thevenin model per pulse, the Saft RC model.

Seed 000 §2 does these by hand in MATLAB; here each step names the paper's equation and the
scipy function that replaces the MATLAB one (fit -> ``curve_fit``, lsqlin -> ``lsq_linear``,
lsqnonlin -> ``least_squares``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.optimize import OptimizeWarning, curve_fit, least_squares, lsq_linear

from ..models.ocv import OcvCurve
from ..series import BatterySeries
from ..units import SECONDS_PER_HOUR
from .segment import IdentificationError, Pulse


def charge_removed_ah(
    test: BatterySeries, gap_s: float = 10.0, notes: list[str] | None = None
) -> np.ndarray:
    """Charge removed since the first sample (Ah).

    With a reference SoC and the capacity behind it (``test.reference_capacity_ah``: a
    tester's amp-hour counter), the charge is the reference's: a tester logging once a minute
    through a C/3 discharge, or dropping from 10 Hz to 1 Hz at a pulse's end, leaves samples
    that do not describe the charge moved (measured on the Panasonic HPPC: holding each sample's
    current over its step overcounts by 0.1 Ah, 3.6 %). Otherwise the current is held between
    samples (zero-order hold), and steps longer than ``gap_s`` are reported in ``notes``.
    """
    dt = np.diff(test.t_s)
    step_ah = test.current_a[:-1] * dt / SECONDS_PER_HOUR
    held = np.concatenate([[0.0], np.cumsum(step_ah)])
    q_ref_ah = test.reference_capacity_ah
    ref = test.soc_ref
    if ref is not None and q_ref_ah is not None and np.all(np.isfinite(ref)):
        q = (ref[0] - ref) * q_ref_ah
        if notes is not None:
            notes.append(
                f"charge from the reference SoC ({q_ref_ah:g} Ah per unit): {q[-1]:.4f} Ah "
                f"over the test; holding the sampled current gives {held[-1]:.4f} Ah"
            )
        return q
    gaps = dt > gap_s
    if np.any(gaps) and notes is not None:
        moved = float(np.sum(np.abs(step_ah[gaps])))
        hint = (
            "; the recording has a reference SoC: give the capacity behind it "
            "(--reference-capacity-ah) to count from it"
            if ref is not None
            else ""
        )
        notes.append(
            f"{int(np.count_nonzero(gaps))} logging gap(s) > {gap_s:g} s carry {moved:.3f} Ah "
            f"by holding the sampled current{hint}"
        )
    return held


def step_current_a(
    t_s: np.ndarray, current_a: np.ndarray, rest_a: float = 0.05, gap_s: float = 10.0
) -> np.ndarray:
    """The current held over each step ``[t_k, t_k+1)`` (the last entry: the last sample's).

    The sample's own current, except across a logging gap (a step over ``gap_s``) that ends at
    rest (|I| <= ``rest_a``): a tester logs a load step's last point when the step ends, so the
    load ended there and the step holds the rest current (the Nissan files: 10 A, then rest
    points once a minute; holding 10 A for that minute would add 0.17 Ah and delay the
    relaxation the fit sees by a minute).
    """
    held = np.array(current_a, dtype=float)
    dt = np.diff(t_s)
    ends_at_rest = (dt > gap_s) & (np.abs(current_a[1:]) <= rest_a)
    held[:-1][ends_at_rest] = current_a[1:][ends_at_rest]
    return held


def branch_response(
    t_s: np.ndarray, current_a: np.ndarray, tau_s: float, block_exp: float = 40.0
) -> np.ndarray:
    """Normalized RC-branch state x (V_i = R_i x) for a current held between samples.

    Exact recursion ``x[k+1] = a_k x[k] + (1 - a_k) I[k]``, ``a_k = exp(-dt_k/tau)``, from rest
    (x[0] = 0), for any sample spacing. The products of the a_k telescope,
    ``a_j ... a_(k-1) = exp(-(t_k - t_j)/tau)``, so within a block starting at sample b::

        x[k] = e^(-(t_k - t_b)/tau) (x[b] + sum_{b<=j<k} e^((t_(j+1) - t_b)/tau) (1 - a_j) I[j])

    a cumulative sum; blocks end before the exponent passes ``block_exp`` (no overflow, and
    the sum's rounding stays 1e-16 of the current). A tester's jittery log (0.100/0.102/0.114 s
    steps, then 1 s, then 60 s) costs a few numpy calls per block instead of one filter call
    per run of equal steps (a million calls for the Panasonic HPPC).
    """
    t = np.asarray(t_s, dtype=float)
    x = np.zeros(t.size)
    if t.size < 2:
        return x
    dt = np.diff(t)
    drive = -np.expm1(-dt / tau_s) * current_a[:-1]  # (1 - a_j) I[j]
    b = 0
    while b < t.size - 1:
        # Samples b+1 .. e are in this block: their exponent (t - t_b)/tau <= block_exp.
        e = int(np.searchsorted(t, t[b] + block_exp * tau_s, side="right")) - 1
        e = min(max(e, b + 1), t.size - 1)
        rel = (t[b + 1 : e + 1] - t[b]) / tau_s
        sums = np.cumsum(np.exp(rel) * drive[b:e])
        x[b + 1 : e + 1] = np.exp(-rel) * (x[b] + sums)
        b = e
    return x


@dataclass(frozen=True)
class PulseFit:
    """2-RC Thevenin parameters of one pulse (pack level) and how well they fit."""

    soc: float
    r0_ohm: float
    r1_ohm: float
    tau1_s: float
    r2_ohm: float
    tau2_s: float
    rmse_linear_v: float
    rmse_v: float


def _relaxation(t, v_inf, a1, tau1, a2, tau2):
    """Seed 000 eq. 18 with the asymptote named: V = V_inf - A1 e^(-t/tau1) - A2 e^(-t/tau2)."""
    return v_inf - a1 * np.exp(-t / tau1) - a2 * np.exp(-t / tau2)


def fit_relaxation(t_s: np.ndarray, v: np.ndarray) -> tuple[float, float, float, float, float]:
    """Eq. 18 over a rest: (V_inf, A1, tau1, A2, tau2), tau1 < tau2, by ``curve_fit``."""
    t = t_s - t_s[0]
    rise = max(float(v[-1] - v[0]), 1e-4)
    span = float(t[-1])
    p0 = (float(v[-1]) + 0.05 * rise, 0.5 * rise, min(30.0, span / 20), 0.5 * rise, span / 4)
    lo = (float(v[-1]) - 0.01, 0.0, 0.5, 0.0, 10.0)
    hi = (float(v[-1]) + 2.0 * rise + 0.01, 10.0 * rise + 0.1, 600.0, 10.0 * rise + 0.1, 5 * span)
    popt, _ = curve_fit(_relaxation, t, v, p0=p0, bounds=(lo, hi), maxfev=20000)
    v_inf, a1, tau1, a2, tau2 = (float(p) for p in popt)
    if tau1 > tau2:
        a1, tau1, a2, tau2 = a2, tau2, a1, tau1
    return v_inf, a1, tau1, a2, tau2


def instantaneous_resistance(test: BatterySeries, p: Pulse) -> float:
    """Eq. 17 (R_t of the paper, R0 here): voltage steps at the pulse's onset and end over
    the current steps, averaged. At 10 Hz the first sample already holds 0.1 s of the fastest
    polarization, as in the paper's own sampling."""
    v, i = test.voltage_v, test.current_a
    r_on = (v[p.rest_before] - v[p.start]) / (i[p.start] - i[p.rest_before])
    r_off = (v[p.end + 1] - v[p.end]) / (i[p.end] - i[p.end + 1])
    return float(0.5 * (r_on + r_off))


#: A pulse's onset is fitted against a straight OCV (``fit_pulse``) unless the OCV table bends
#: by more than this over it (V): measured on the bags' pulse tests, LFP leaving full bends
#: 14.5 mV over 3 min at 0.2 C, every other onset <= 1.1 mV (SLA <= 0.1 mV).
ONSET_BEND_V = 0.005


def ocv_bend_v(ocv: OcvCurve, soc: np.ndarray) -> float:
    """Largest distance (V) of the OCV along ``soc`` (monotone) from the chord of its ends."""
    soc = np.asarray(soc, dtype=float)
    if soc.size < 3 or soc[-1] == soc[0]:
        return 0.0
    v = ocv.ocv_array(soc)
    chord = v[0] + (v[-1] - v[0]) * (soc - soc[0]) / (soc[-1] - soc[0])
    return float(np.max(np.abs(v - chord)))


def onset_soc(test: BatterySeries, p: Pulse, soc_at: np.ndarray, window_s: float = 180.0):
    """The SoC over a pulse's first ``window_s`` (the onset window of ``fit_pulse``)."""
    k1 = int(np.searchsorted(test.t_s, test.t_s[p.start] + window_s, side="right"))
    return soc_at[p.start : min(k1, p.end + 1)]


def fit_pulse(
    test: BatterySeries,
    p: Pulse,
    soc_at: np.ndarray,
    onset_window_s: float = 180.0,
    min_tau_s: float = 0.5,
    anchor_end: bool = False,
) -> PulseFit:
    """Fit one pulse window: eq. 17 (start), eq. 18 (``curve_fit``), lsqlin, lsqnonlin.

    The fits use the data where the OCV is known without a model of its path: the rest after
    the excitation (OCV constant, the relaxation of eq. 18) and its first ``onset_window_s``,
    against the rested voltage before it with a local OCV slope per ampere-hour removed (the
    charge, not the time, so that an excitation of several steps -- pulse, rest, regen,
    discharge -- is one linear model). Fitting a whole 30-min pulse would need the OCV along
    it, and any error in that path (a fraction of a millivolt between rest points) is absorbed
    by R0 and the fast branch: tested, it biased R0 by up to 15 %.

    With ``anchor_end`` the loaded window is the excitation's last ``onset_window_s``
    instead, against the rest's own asymptote (the OCV where the excitation ended, the same
    local slope): for a pulse whose onset crosses a bend of the OCV (LFP leaving full: 600 mV
    over the first 3 min at 0.2 C, 15 mV from a straight line), where no slope describes the
    OCV along the onset and R0 and the fast branch would absorb the bend (measured: R0 0.17
    instead of 0.06 ohm, which put the model 100 mV low at SoC 0.9-0.95). The fit is then
    labelled with the SoC of that window, where the relaxation after it also belongs.
    """
    v_all, i_all, t_all = test.voltage_v, test.current_a, test.t_s
    sl = slice(p.rest_before, p.rest_end + 1)
    t = t_all[sl] - t_all[p.rest_before]
    i = i_all[sl]
    v = v_all[sl]
    i_held = step_current_a(t, i)  # what each step held (the R0 term uses the sample's own)
    # Rested voltage before the pulse: mean of the last minute of the rest.
    k_rest0 = int(np.searchsorted(t_all, t_all[p.rest_before] - 60.0))
    v_rest = float(np.mean(v_all[k_rest0 : p.rest_before + 1]))
    k_end = p.end - p.rest_before  # index of the last sample of the excitation
    rest = np.arange(t.size) > k_end
    # Charge removed since the excitation began (Ah).
    q_ah = np.concatenate([[0.0], np.cumsum(i_held[:-1] * np.diff(t))]) / SECONDS_PER_HOUR
    if anchor_end:
        # The excitation's last window: OCV = V_inf + k (q_end - q), V_inf the rest's.
        loaded = (t >= t[k_end] - onset_window_s + 1e-9) & ~rest
        q_loaded = np.where(loaded, q_ah - q_ah[k_end], 0.0)
        anchored = rest | loaded
        v_anchor = 0.0
        r0 = float(
            (v[k_end + 1] - v[k_end]) / (i[k_end] - i[k_end + 1])
        )  # eq. 17 at the end only: the onset's step belongs to the bend
    else:
        loaded = (t > 0.0) & (t <= t[1] + onset_window_s - 1e-9) & ~rest
        q_loaded = np.where(loaded, q_ah, 0.0)
        anchored = rest
        v_anchor = v_rest
        r0 = instantaneous_resistance(test, p)
    use = loaded | rest

    _, _, tau1, _, tau2 = fit_relaxation(t[rest], v[rest])

    def design(tau1_: float, tau2_: float) -> np.ndarray:
        """Columns for [V_inf, R0, R1, R2, k]: the measured voltage is their combination
        (k: the OCV's slope in V/Ah over the loaded window)."""
        x1, x2 = branch_response(t, i_held, tau1_), branch_response(t, i_held, tau2_)
        return np.column_stack([anchored * 1.0, -i * loaded, -x1, -x2, -q_loaded])[use]

    target = (v - v_anchor * (loaded & ~anchored))[use]
    # lsqlin: with the time constants of eq. 18, the model is linear in the rest asymptote,
    # the three resistances and the local OCV slope; resistances bounded >= 0.
    a_mat = design(tau1, tau2)
    lin = lsq_linear(a_mat, target, bounds=([-np.inf, 0, 0, 0, -np.inf], np.inf))
    v_inf, r0_l, r1, r2, slope = (float(x) for x in lin.x)
    r0 = r0_l if r0_l > 0 else r0
    rmse_lin = float(np.sqrt(np.mean((a_mat @ lin.x - target) ** 2)))

    # lsqnonlin: refine with the time constants free, from the linear result; analytic
    # Jacobian (linear in all but the time constants, d x / d tau by a forward difference).
    def residual(q: np.ndarray) -> np.ndarray:
        return design(q[5], q[6]) @ q[:5] - target

    def jacobian(q: np.ndarray) -> np.ndarray:
        base = design(q[5], q[6])
        h1, h2 = 1e-4 * q[5], 1e-4 * q[6]
        d1 = (design(q[5] + h1, q[6])[:, 2] - base[:, 2]) / h1 * q[2]
        d2 = (design(q[5], q[6] + h2)[:, 3] - base[:, 3]) / h2 * q[3]
        return np.column_stack([base, d1, d2])

    start = np.array([v_inf, r0, max(r1, 1e-6), max(r2, 1e-6), slope, max(tau1, min_tau_s), tau2])
    # Time constants: the fast branch within what 10 Hz samples resolve and a 3-min onset
    # window shows; the slow branch within the 1-h rest that measures it.
    lower = np.array([v_inf - 0.5, 0.0, 0.0, 0.0, -1e3, min_tau_s, 60.0])
    upper = np.array([v_inf + 0.5, 1.0, 1.0, 1.0, 1e3, 300.0, 5000.0])
    start = np.clip(start, lower + 1e-9, upper - 1e-9)
    sol = least_squares(
        residual,
        start,
        jac=jacobian,
        bounds=(lower, upper),
        x_scale=np.array([1e-2, 1e-2, 1e-2, 1e-2, 0.1, 10.0, 300.0]),
    )
    _, r0_f, r1_f, r2_f, _, tau1_f, tau2_f = (float(x) for x in sol.x)
    if tau1_f > tau2_f:
        r1_f, tau1_f, r2_f, tau2_f = r2_f, tau2_f, r1_f, tau1_f
    window = slice(p.rest_before, p.end + 1)
    labelled = (i_all[window] > 0) & (loaded[: k_end + 1] if anchor_end else True)
    return PulseFit(
        soc=float(np.mean(soc_at[window][labelled])),
        r0_ohm=r0_f,
        r1_ohm=max(r1_f, 1e-6),
        tau1_s=tau1_f,
        r2_ohm=max(r2_f, 1e-6),
        tau2_s=tau2_f,
        rmse_linear_v=rmse_lin,
        rmse_v=float(np.sqrt(np.mean(sol.fun**2))),
    )


@dataclass(frozen=True)
class RcFit:
    """Saft RC model values of one pulse (seed 000 eqs. 6-10)."""

    r_total_ohm: float
    r_b_ohm: float
    r_s_ohm: float
    r_t_ohm: float
    tau_s: float
    c_s_f: float


def fit_rc_pulse(test: BatterySeries, p: Pulse, window_s: float = 5.0) -> RcFit:
    """Eqs. 6-8 from the onset step; eq. 9 over the start of the rest; eq. 10.

    Eq. 9 uses the first 500 ms after the load is removed. At 10 Hz that is five samples,
    too few to fit a time constant through quantization noise, so the fit runs over the first
    ``window_s`` (5 s, 50 samples): the same exponential, a window matched to the sample rate.
    """
    v, i, t = test.voltage_v, test.current_a, test.t_s
    r_total = (v[p.rest_before] - v[p.start]) / (i[p.start] - i[p.rest_before])  # eq. 6
    r_b = r_s = 0.75 * r_total  # eq. 7
    r_t = r_total - r_b / 2.0  # eq. 8
    k0 = p.end + 1
    k1 = int(np.searchsorted(t, t[k0] + window_s))
    tt = t[k0:k1] - t[k0]
    vv = v[k0:k1]
    v_start = float(vv[0])

    def eq9(x, v_end, tau):
        return v_start + (v_end - v_start) * (1.0 - np.exp(-x / tau))

    try:
        with warnings.catch_warnings():
            # At 1 Hz the window holds five points: the fit stands, its covariance does not.
            warnings.simplefilter("ignore", OptimizeWarning)
            (v_end, tau), _ = curve_fit(
                eq9,
                tt,
                vv,
                p0=(float(vv[-1]), window_s / 3),
                bounds=((v_start - 1.0, 0.05), (v_start + 1.0, 60.0)),
            )
    except (RuntimeError, ValueError) as exc:
        raise IdentificationError(f"eq. 9 fit failed after the pulse at t={t[k0]:.0f} s") from exc
    return RcFit(r_total, r_b, r_s, r_t, float(tau), float(tau) / (2.0 * r_s))  # eq. 10


def monotone_ocv_table(soc: np.ndarray, ocv: np.ndarray, min_step_v: float = 1e-4):
    """Sort by SoC and force a strictly increasing OCV (a PCHIP table needs it).

    Points that break monotonicity (noise on a flat plateau) are raised to the previous
    point plus ``min_step_v``; the change is reported by the caller.
    """
    order = np.argsort(soc)
    s, v = np.asarray(soc, dtype=float)[order], np.asarray(ocv, dtype=float)[order]
    s = np.clip(s, 0.0, 1.0)  # sensor offset can count a rested full pack a hair above 1
    keep = np.concatenate([[True], np.diff(s) > 1e-6])
    s, v = s[keep], v[keep]
    fixed = v.copy()
    for k in range(1, fixed.size):
        fixed[k] = max(fixed[k], fixed[k - 1] + min_step_v)
    return s, fixed, int(np.count_nonzero(fixed != v))
