r"""The robust running mean of pair differences that the autopilot-bias steps share.

:mod:`mavahrs.ingest.autopilot_bias` (the gyro, rad/s) and :mod:`mavahrs.ingest.autopilot_mag_bias` (the
field, µT) both pair a sample of the autopilot's corrected message with one of its bias-free twin, and keep
the mean of the differences ``d`` (twin − corrected) as the bias to add back:

    b_k = b_{k-1} + α_k (d_k − b_{k-1}),   α_k = min(1, Δt_k / τ)      (the first ``min_pairs``: arithmetic mean)

A difference beyond ``max_bias`` on an axis is no pair; one further than ``outlier`` from the mean is an
outlier, not used, and ``min_pairs`` in a row (the autopilot reset its bias) restart the mean from the new
pair; no pair for ``hold`` restarts it too.  The mean is trusted (:func:`mean_trusted`) once ``min_pairs``
pairs made it, while its last pair is at most ``hold`` old and the outliers' share (mean over τ) is at most
``max_outlier_fraction``.

Each step's state array starts with this mean (:data:`MEAN_LEN` values: :data:`S_B` … :data:`S_CONSEC`) and
its constants with the ones here (:data:`P_LEN`: :data:`P_TAU_US` … :data:`P_MAX_FRAC`); each step keeps
its own after those.  Its counters (:func:`counter_names`) are a block in its state whose start it passes.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from mavahrs.filters.jit import kernel

__all__ = [
    "S_B",
    "S_N",
    "S_T_LAST",
    "S_R",
    "S_CONSEC",
    "MEAN_LEN",
    "P_TAU_US",
    "P_MIN_PAIRS",
    "P_HOLD_US",
    "P_MAX_BIAS",
    "P_OUTLIER",
    "P_MAX_FRAC",
    "P_LEN",
    "C_PAIRS",
    "C_SECOND",
    "C_BAD",
    "C_OUTLIERS",
    "C_RESTARTS",
    "C_BACK",
    "C_APPLIED",
    "C_NOT_APPLIED",
    "counter_names",
    "clear_mean",
    "pair_mean_update",
    "mean_trusted",
    "trusted_mean",
    "counter_values",
]

# state: the mean (3), its pair count, the last pair's stamp (µs), the outlier rate, outliers in a row
S_B, S_N, S_T_LAST, S_R, S_CONSEC = 0, 3, 4, 5, 6
MEAN_LEN = 7
# constants: τ (µs), pairs before the mean is trusted, the hold (µs), the largest bias, the outlier gate, the
# largest outlier share
P_TAU_US, P_MIN_PAIRS, P_HOLD_US, P_MAX_BIAS, P_OUTLIER, P_MAX_FRAC = range(6)
P_LEN = 6
# counters, from the start of the step's block (the second is the step's own: unpaired, uncalibrated, …)
C_PAIRS, C_SECOND, C_BAD, C_OUTLIERS, C_RESTARTS, C_BACK, C_APPLIED, C_NOT_APPLIED = range(8)


def counter_names(second: str) -> tuple[str, ...]:
    """The names of a step's counters, in their order; ``second`` names the step's own (:data:`C_SECOND`)."""
    return ("pairs", second, "bad_values", "outliers", "restarts", "clock_back", "applied", "not_applied")


@kernel
def clear_mean(st):  # type: ignore[no-untyped-def]
    """Forget the mean (no pair, no outlier)."""
    st[S_B] = st[S_B + 1] = st[S_B + 2] = 0.0
    st[S_N] = 0.0
    st[S_T_LAST] = -math.inf
    st[S_R] = 0.0
    st[S_CONSEC] = 0.0


@kernel
def pair_mean_update(st, p, c, t, d0, d1, d2):  # type: ignore[no-untyped-def]
    """One pair's difference ``d`` (twin − corrected) at stamp ``t`` (µs) into the mean; ``c``: where the
    step's counters start in ``st``."""
    lim = p[P_MAX_BIAS]
    if not (abs(d0) <= lim and abs(d1) <= lim and abs(d2) <= lim):  # NaN fails too
        st[c + C_BAD] += 1.0
        return
    st[c + C_PAIRS] += 1.0
    n = st[S_N]
    if n > 0.0 and t - st[S_T_LAST] > p[P_HOLD_US]:  # no pair for longer than the hold: start again
        st[c + C_RESTARTS] += 1.0
        n = 0.0
        st[S_R] = 0.0
        st[S_CONSEC] = 0.0
    if n < p[P_MIN_PAIRS]:  # the first pairs: their arithmetic mean (Welford)
        k = 1.0 / (n + 1.0)  # 1 for the first pair: the mean is that pair
        st[S_B] += k * (d0 - st[S_B])
        st[S_B + 1] += k * (d1 - st[S_B + 1])
        st[S_B + 2] += k * (d2 - st[S_B + 2])
        st[S_N] = n + 1.0
        st[S_T_LAST] = t
        return
    a = min(1.0, max(0.0, t - st[S_T_LAST]) / p[P_TAU_US])
    e0, e1, e2 = d0 - st[S_B], d1 - st[S_B + 1], d2 - st[S_B + 2]
    g = p[P_OUTLIER]
    if abs(e0) > g or abs(e1) > g or abs(e2) > g:
        st[c + C_OUTLIERS] += 1.0
        st[S_R] += a * (1.0 - st[S_R])
        st[S_CONSEC] += 1.0
        if st[S_CONSEC] >= p[P_MIN_PAIRS]:  # a step (the autopilot reset its bias): the mean starts from this pair
            st[c + C_RESTARTS] += 1.0
            st[S_B], st[S_B + 1], st[S_B + 2] = d0, d1, d2
            st[S_N] = 1.0
            st[S_R] = 0.0
            st[S_CONSEC] = 0.0
            st[S_T_LAST] = t
        return
    st[S_CONSEC] = 0.0
    st[S_R] -= a * st[S_R]
    st[S_B] += a * e0
    st[S_B + 1] += a * e1
    st[S_B + 2] += a * e2
    st[S_N] = n + 1.0
    st[S_T_LAST] = t


@kernel
def mean_trusted(st, p, t):  # type: ignore[no-untyped-def]
    """Whether the mean is to be added at stamp ``t`` (µs): ``min_pairs`` pairs, the last at most ``hold`` old,
    few outliers."""
    return st[S_N] >= p[P_MIN_PAIRS] and t - st[S_T_LAST] <= p[P_HOLD_US] and st[S_R] <= p[P_MAX_FRAC]


def trusted_mean(st: NDArray[np.float64], p: NDArray[np.float64], t: float) -> tuple[float, float, float] | None:
    """The mean as the step adds it at stamp ``t`` (µs; the newest primary stamp), or None while none is trusted."""
    if not mean_trusted(st, p, t):
        return None
    return float(st[S_B]), float(st[S_B + 1]), float(st[S_B + 2])


def counter_values(st: NDArray[np.float64], c: int, names: tuple[str, ...]) -> dict[str, int]:
    """A step's counters by name (:func:`counter_names`), its block starting at ``c`` in ``st``."""
    return {name: int(st[c + i]) for i, name in enumerate(names)}
