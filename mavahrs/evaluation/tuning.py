r"""Madgwick's β and ζ, and the gyro temperature-bias model, from a stationary recording.

Selezneva & Kumarin (004), eq. (1)–(5), with Madgwick 2010, eq. (47)–(51):

1. **Gyro zero drift vs temperature.**  At rest the true rate is zero, so
   each gyro axis reads its bias plus noise.  Per axis a straight line
   ``α_k(T) = b0_k + k_k·(T − T₀)`` is fitted by least squares (004: "linear
   approximation of the gyro readings at zero rate and different
   temperatures").  Without a usable temperature (absent, or a spread below
   ``min_temperature_span_c``) the bias is fitted as a line in *time* instead
   and no temperature model is written.
2. **Noise.**  What the line does not explain is measurement noise ϑ_t (004).
   Its mean absolute value per axis is Madgwick's ω̃_β, "the estimated mean
   zero-mean gyroscope measurement error of each axis".
3. **β and ζ from the sensor figures** (Madgwick 2010, eq. (50)–(51)):
   ``β = √(3/4)·ω̃_β`` and ``ζ = √(3/4)·ω̃_ζ``, with ω̃_ζ the bias drift rate
   per axis: the RMS over axes of ``k_k`` times the RMS rate of temperature
   change (from 5 s block means; or the fitted time slope without temperature).
4. **β and ζ by least squares** (004, eq. (3)–(5)): one scalar gain μ
   fitting ``μ·v_t ≈ w_t`` over all samples is ``μ = tr(VᵀW)/tr(VᵀV)``.

   * β (eq. (2), (4)): ``w_t = ½ q ⊗ [0, ϑ_t]`` is the quaternion rate the
     noise alone causes; ``v_t = ∇f/‖∇f‖`` is the normalised gradient of
     Madgwick's objective (eq. (25)–(34), gravity and — with a magnetometer
     — the compensated field of eq. (46)) at the attitude that noise would
     produce, i.e. the direction the correction acts in.
   * ζ (eq. (1), (3)): the bias estimate ``ζ·Σ ω_ε Δt`` (eq. (47)–(48),
     ``ω_ε = 2 q* ⊗ ∇f/‖∇f‖``) should follow the drift
     ``A_t = α(T_t) − α(T_0)``; the gradient is taken at the attitude error
     the uncorrected drift would have accumulated.

   Taken literally with the gradient of a running filter, eq. (4) projects
   the instantaneous gyro noise on a direction dominated by accelerometer
   noise and gives μ ≈ 0 — the paper's own β = −1.3·10⁻⁴ shows this.  Here
   the gradient is evaluated on the noise-free field directions (the
   recording's mean accelerometer and magnetometer) at the attitude the
   gyro error alone produces, which is what eq. (1)–(2) describe.  For
   isotropic noise this lands close to the spec formula, so the two columns
   are a consistency check of each other.

Output: :class:`TuneResult` with ``to_toml()`` — the layout ``mavahrs run
--config`` reads (:mod:`mavahrs.config`): ``[pipeline] filter_name = "madgwick"``,
the temperature model in ``[pipeline.calibration.gyro_temperature]``
(:class:`mavahrs.sensors.calibration.GyroTemperatureModel` fields ``b0_rad_s``,
``k_rad_s_per_c``, ``t0_c``) and the gains in ``[filter.madgwick]``
(``beta_rad_s``, ``zeta_rad_s``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mavahrs.errors import DataError
from mavahrs.evaluation.datasets import Recording
from mavahrs.geometry.quaternion import conjugate, from_rotation_vector, multiply
from mavahrs.geometry.rotation import from_matrix

__all__ = [
    "TuneSettings",
    "TuneResult",
    "tune",
    "tune_file",
    "combine",
    "least_squares_gain",
    "least_squares_terms",
    "SPEC_FACTOR",
]

Array = NDArray[np.float64]

#: √(3/4): Madgwick 2010, eq. (50)–(51).
SPEC_FACTOR = math.sqrt(0.75)


@dataclass(frozen=True)
class TuneSettings:
    """Options of :func:`tune`.

    Attributes:
        min_temperature_span_c: below this temperature spread (°C) no
            temperature model is fitted (the slope would be noise).
        outlier_sd: samples whose residual exceeds this many robust standard
            deviations on any axis are dropped (bumps, not noise), then the
            fits are repeated once.
        block_s: block length for the temperature-rate estimate, s.
        max_motion_rad_s: a residual above this on any axis means the
            recording is not stationary; more than 1 % such samples is an error.
    """

    min_temperature_span_c: float = 1.0
    outlier_sd: float = 6.0
    block_s: float = 5.0
    max_motion_rad_s: float = math.radians(10.0)

    def __post_init__(self) -> None:
        for name in ("min_temperature_span_c", "outlier_sd", "block_s", "max_motion_rad_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")


@dataclass(frozen=True)
class TuneResult:
    """What :func:`tune` measured (SI units unless the name says otherwise)."""

    name: str
    samples: int
    duration_s: float
    rate_hz: float
    axes: int  # 9 = the least-squares gradient used the magnetometer, 6 = gravity only
    temperature_model: bool
    t0_c: float
    temperature_range_c: tuple[float, float]
    b0_rad_s: tuple[float, float, float]
    k_rad_s_per_c: tuple[float, float, float]
    drift_rad_s2: tuple[float, float, float]  # time slope when there is no temperature model
    noise_sd_rad_s: tuple[float, float, float]
    noise_mean_abs_rad_s: tuple[float, float, float]
    omega_beta_rad_s: float
    omega_zeta_rad_s2: float
    temperature_rate_c_s: float
    beta_spec: float
    zeta_spec: float
    beta_ls: float
    zeta_ls: float
    dropped_samples: int
    notes: list[str] = field(default_factory=list)
    #: (tr(VᵀW), tr(VᵀV)) of the β and ζ least-squares fits: they add up over recordings (:func:`combine`)
    beta_ls_terms: tuple[float, float] = (math.nan, math.nan)
    zeta_ls_terms: tuple[float, float] = (math.nan, math.nan)
    #: how many recordings the result is over (:func:`combine`: more than one, and no temperature model)
    recordings: int = 1

    def no_temperature_model_reason(self) -> str:
        """Why the result holds no gyro temperature model, in words (for messages and the TOML file)."""
        if self.recordings > 1:
            return (f"one set of gains over {self.recordings} recordings, and the gyro bias differs per power-up "
                    "(`mavahrs tune LOG` fits each recording's own model)")  # fmt: skip
        return "the recording's IMU temperature did not spread enough for one"

    def format(self) -> str:
        d3 = np.degrees
        lines = [
            f"{self.name}: {self.samples} samples, {self.duration_s:.1f} s, {self.rate_hz:.1f} Hz",
        ]
        if self.temperature_model:
            lines.append(
                f"temperature {self.temperature_range_c[0]:.2f} … {self.temperature_range_c[1]:.2f} °C "
                f"(reference T0 = {self.t0_c:.2f} °C, RMS rate {self.temperature_rate_c_s * 60:.3f} °C/min)"
            )
        lines.append("gyro zero drift, per axis x / y / z:")
        lines.append("  bias at T0      " + _three(d3(self.b0_rad_s), "°/s", 4))
        if self.temperature_model:
            lines.append("  temp. slope     " + _three(d3(self.k_rad_s_per_c), "°/s per °C", 5))
        elif not all(math.isfinite(v) for v in self.drift_rad_s2):  # combined over recordings each with a model
            lines.append("  temp. slope     per recording (each its own temperature model: `mavahrs tune LOG`)")
        else:
            lines.append("  drift in time   " + _three(d3(self.drift_rad_s2), "°/s per s", 6))
        lines.append("  noise SD        " + _three(d3(self.noise_sd_rad_s), "°/s", 4))
        lines.append("  noise mean |ϑ|  " + _three(d3(self.noise_mean_abs_rad_s), "°/s", 4))
        lines.append(f"ω̃_β = {self.omega_beta_rad_s:.6f} rad/s, ω̃_ζ = {self.omega_zeta_rad_s2:.3e} rad/s²")
        lines.append(f"{'':24}{'spec (eq. 50–51)':>18}{'least squares (004)':>22}")
        lines.append(f"{'β  (rad/s)':24}{self.beta_spec:18.6f}{self.beta_ls:22.6f}")
        lines.append(f"{'ζ  (rad/s²)':24}{self.zeta_spec:18.3e}{self.zeta_ls:22.3e}")
        lines.append(f"(least squares on the {'MARG' if self.axes == 9 else 'IMU'} objective)")
        if self.dropped_samples:
            lines.append(f"dropped {self.dropped_samples} outlier samples (bumps) before fitting")
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for k in self.__dataclass_fields__:
            v = getattr(self, k)
            out[k] = list(v) if isinstance(v, tuple) else v
        return out

    def gains(self, which: str = "flight") -> tuple[float, float]:
        """(β rad/s, ζ rad/s²) to write: ``"spec"`` (eq. 50–51), ``"ls"`` (least squares) or ``"flight"``.

        ``flight``: Madgwick's default flight gains (:class:`MadgwickSettings`).
        A recording at rest measures the gyro's noise only; in flight the gyro
        error also holds vibration, scale and cross-axis errors and bias
        changes, which the gains must correct, so bench gains are far too small
        to fly with (:meth:`flight_warning`).  ``to_toml(gains="flight")``
        writes no gains at all: the daemon's default filter runs with its own
        flight defaults.
        """
        if which == "spec":
            return self.beta_spec, self.zeta_spec
        if which == "ls":
            return self.beta_ls, self.zeta_ls
        if which == "flight":
            from mavahrs.filters.madgwick import MadgwickSettings

            d = MadgwickSettings()
            return d.beta_rad_s, d.zeta_rad_s
        raise ValueError(f"gains must be 'flight', 'spec' or 'ls', got {which!r}")

    def unusable(self, which: str) -> str | None:
        """Why :meth:`to_toml` with ``gains=which`` would write nothing usable (None when it is fine).

        Non-finite or non-positive gains (``spec``/``ls``), a non-finite temperature
        model, or a ``flight`` file that would hold no settings at all.
        """
        if self.temperature_model and not all(
            math.isfinite(v) for v in (self.t0_c, *self.b0_rad_s, *self.k_rad_s_per_c)
        ):
            return "the gyro temperature model is not finite"
        if which == "flight":
            if not self.temperature_model:
                record = ("tune each recording alone for its model" if self.recordings > 1
                          else "record a warm-up at rest")  # fmt: skip
                return (f"nothing to write: no temperature model ({self.no_temperature_model_reason()}) and "
                        f"--gains flight writes no gains; {record}, or ask for bench gains with --gains spec or ls")
            return None
        beta, zeta = self.gains(which)
        bad = [f"{n} = {v:.3g}" for n, v in (("β", beta), ("ζ", zeta)) if not (math.isfinite(v) and v >= 0)]
        if not bad and not beta > 0:
            bad = [f"β = {beta:.3g}"]
        if bad:
            return (f"not enough motion / rest to estimate the {which} gains ({', '.join(bad)}): "
                    "nothing written")  # fmt: skip
        return None

    def flight_warning(self, which: str) -> str | None:
        """Why the ``which`` gains are not fit to fly with (None for ``flight``, or gains as large as those)."""
        beta, zeta = self.gains(which)
        f_beta, f_zeta = self.gains("flight")
        if beta >= f_beta:
            return None
        ten_deg = math.radians(10.0)
        zeta_text = "; ζ = 0 tracks no gyro-bias change at all" if zeta == 0 else ""
        if self.temperature_model:
            advice = "for flight use --gains flight (the default), which keeps this recording's gyro temperature model"
        elif self.recordings > 1:  # combine() writes no temperature model (unusable())
            advice = ("for flight run without these gains (the filters' own flight gains), with a gyro temperature "
                      "model from one recording (`mavahrs tune LOG`): one set over several recordings has none, "
                      "as the gyro bias differs per power-up")  # fmt: skip
        else:  # --gains flight writes only a temperature model, and this recording gives none (unusable())
            advice = ("for flight run without these gains (the filters' own flight gains); this recording gives "
                      "no gyro temperature model (its IMU temperature did not spread), so --gains flight would "
                      "write nothing from it: record a warm-up at rest for one")  # fmt: skip
        return (
            f"β = {beta:.3g} rad/s ({which}) measures the gyro's noise at rest: the filter would take "
            f"{_duration(ten_deg / beta)} to correct a 10° attitude error (flight gain {f_beta:.3g} rad/s: "
            f"{_duration(ten_deg / f_beta)}){zeta_text}. Fine on a bench, not fit to fly with: {advice}"
        )

    def to_toml(self, *, gains: str = "flight") -> str:
        """The settings file ``mavahrs run --config`` reads.

        Args:
            gains: ``"flight"`` (default): no gains, the daemon's default filter with its flight
                defaults, plus the gyro temperature model; ``"spec"`` (eq. 50–51) or ``"ls"``: the
                Madgwick gains fitted at rest (:meth:`gains`), with a comment when they are not fit to fly.
        """
        beta, zeta = self.gains(gains)
        warning = self.flight_warning(gains)
        if gains == "flight":
            pipeline = [
                "# no filter_name: the daemon's default filter (best) with its own flight gains; the",
                "# Madgwick gains fitted at rest are below as comments (a bench's, not a flight's)",
            ]
        else:
            pipeline = [
                "# the gains below are Madgwick's; pick another filter with --filter (its table is then unused)",
                'filter_name = "madgwick"',
            ]
        lines = [
            f"# Written by `mavahrs tune` from {self.name} ({self.samples} samples, "
            f"{self.duration_s:.0f} s).",
            "# Use with: mavahrs run --config THIS_FILE  (flags on the command line still override it).",
            "",
            "[pipeline]",
            *pipeline,
            "",
        ]
        if self.temperature_model:
            lines += [
                "# Gyro zero drift vs temperature, b(T) = b0 + k·(T − t0), subtracted from the gyro",
                "# whenever the IMU message carries a temperature (RAW_IMU / SCALED_IMU `temperature`).",
                f"# Fitted over {self.temperature_range_c[0]:.2f} … {self.temperature_range_c[1]:.2f} °C.",
                "[pipeline.calibration.gyro_temperature]",
                f"b0_rad_s = {_toml_vec(self.b0_rad_s)}",
                f"k_rad_s_per_c = {_toml_vec(self.k_rad_s_per_c)}",
                f"t0_c = {self.t0_c:.4f}",
                "",
            ]
        else:
            lines += [
                f"# No temperature model: {self.no_temperature_model_reason()}.",
                f"# Mean gyro bias was {_toml_vec(self.b0_rad_s)} rad/s (not written: it changes per power-up).",
                "",
            ]
        if gains == "flight":
            return "\n".join(
                [
                    *lines,
                    "# Madgwick gains fitted at rest, NOT written (a bench's gains, not fit to fly with):",
                    f"#   spec beta = {self.beta_spec:.6g} rad/s, zeta = {self.zeta_spec:.6g} rad/s^2; "
                    f"least squares beta = {self.beta_ls:.6g}, zeta = {self.zeta_ls:.6g}",
                    f"#   omega_beta = {self.omega_beta_rad_s:.6g} rad/s (mean |gyro noise| per axis), "
                    f"omega_zeta = {self.omega_zeta_rad_s2:.6g} rad/s^2 (bias drift rate per axis).",
                    "# `mavahrs tune --gains spec` writes them, for bench tests.",
                    "",
                ]
            )
        source = {
            "spec": "the sensor-spec formulas, Madgwick 2010 eq. (50)-(51)",
            "ls": "the least-squares method of Selezneva & Kumarin, eq. (5)",
        }[gains]
        lines += [
            f"# Madgwick gains from {source}.",
            f"#   omega_beta = {self.omega_beta_rad_s:.6g} rad/s (mean |gyro noise| per axis), "
            f"omega_zeta = {self.omega_zeta_rad_s2:.6g} rad/s^2 (bias drift rate per axis).",
            f"# Fitted at rest: spec beta = {self.beta_spec:.6g}, zeta = {self.zeta_spec:.6g}; "
            f"least squares beta = {self.beta_ls:.6g}, zeta = {self.zeta_ls:.6g}.",
        ]
        if warning is not None:
            lines += ["# NOT FIT TO FLY WITH: " + warning + "."]
        lines += [
            "[filter.madgwick]",
            f"beta_rad_s = {beta:.6g}",
            f"zeta_rad_s = {zeta:.6g}",
            "",
        ]
        return "\n".join(lines)


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.0f} h"


def _three(v: Any, unit: str, digits: int) -> str:
    return " / ".join(f"{float(x):+.{digits}f}" for x in v) + f" {unit}"


def _toml_vec(v: Any) -> str:
    return "[" + ", ".join(f"{float(x):.9g}" for x in v) + "]"


def least_squares_terms(v: Array, w: Array) -> tuple[float, float]:
    """``(tr(VᵀW), tr(VᵀV))``: the sums whose ratio is the least-squares gain; over several
    recordings the sums add up (one gain fitting all their samples)."""
    v = np.asarray(v, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    return float(np.sum(v * w)), float(np.sum(v * v))


def _ratio(terms: tuple[float, float]) -> float:
    num, den = terms
    return num / den if den > 0 else float("nan")


def least_squares_gain(v: Array, w: Array) -> float:
    """The scalar μ minimising Σ‖μ·v_t − w_t‖²: ``tr(VᵀW)/tr(VᵀV)`` (004, eq. (5))."""
    return _ratio(least_squares_terms(v, w))


# --------------------------------------------------------------------------- Madgwick objective


def _rotate_to_body(q_body_to_ned: Array, v_ned: Array) -> Array:
    """``q* ⊗ [0, v] ⊗ q`` without normalising q (its scale matters for the gradient)."""
    qc = conjugate(q_body_to_ned)
    vq = np.concatenate([np.zeros(v_ned.shape[:-1] + (1,)), v_ned], axis=-1)
    return multiply(multiply(qc, vq), q_body_to_ned)[..., 1:]


def _objective(q: Array, refs: list[tuple[Array, Array]]) -> Array:
    """Madgwick 2010, eq. (25)/(29)/(31): stacked f = q*⊗d⊗q − s for each (d_ned, s_body)."""
    return np.concatenate([_rotate_to_body(q, d) - s for d, s in refs], axis=-1)


def _gradient_direction(q: Array, refs: list[tuple[Array, Array]], h: float = 1e-7) -> Array:
    """∇(½‖f‖²) = Jᵀf (eq. (20), (34)) by central differences, normalised (eq. (44))."""
    g = np.empty_like(q)
    for i in range(4):
        e = np.zeros(4)
        e[i] = h
        fp = _objective(q + e, refs)
        fm = _objective(q - e, refs)
        f0 = _objective(q, refs)
        g[..., i] = np.sum(f0 * (fp - fm), axis=-1) / (2 * h)
    n = np.linalg.norm(g, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, g / n, 0.0)


def _rest_attitude(accel_mean: Array, mag_mean: Array | None) -> Array:
    """q_body_to_ned from the mean specific force (+ field) at rest (TRIAD)."""
    down = -accel_mean / np.linalg.norm(accel_mean)  # specific force points up at rest
    if mag_mean is not None:
        east = np.cross(down, mag_mean)
    else:
        east = np.cross(down, np.array([1.0, 0.0, 0.0]))
        if np.linalg.norm(east) < 1e-6:
            east = np.cross(down, np.array([0.0, 1.0, 0.0]))
    east /= np.linalg.norm(east)
    north = np.cross(east, down)
    c_body_to_ned = np.vstack([north, east, down])  # rows: NED axes in body coordinates
    return np.asarray(from_matrix(c_body_to_ned), dtype=np.float64)


# --------------------------------------------------------------------------- the fit


def _bias_fit(
    x: Array, gyro: Array, keep: NDArray[np.bool_], truth: Array | None, t: Array
) -> tuple[Array, Array, Array]:
    """Per axis, least squares ω_k = b0_k + k_k·x (+ S_k·ω_true + τ_k·ω̇_true,k when the truth is known).

    Returns (b0, k, residual of every sample).
    """
    n = gyro.shape[0]
    b0 = np.zeros(3)
    k = np.zeros(3)
    resid = np.empty_like(gyro)
    base = [np.ones(n), x]
    if truth is not None:
        w = np.nan_to_num(truth)
        dt = np.gradient(t) if n > 1 else np.ones(n)
        wdot = np.gradient(w, axis=0) / np.where(dt > 0, dt, 1.0)[:, None]
    for ax in range(3):
        cols = list(base)
        if truth is not None:
            cols += [w[:, 0], w[:, 1], w[:, 2], wdot[:, ax]]
        a_mat = np.column_stack(cols)
        coef, *_ = np.linalg.lstsq(a_mat[keep], gyro[keep, ax], rcond=None)
        b0[ax], k[ax] = coef[0], coef[1]
        extra = a_mat[:, 2:] @ coef[2:] if truth is not None else 0.0
        resid[:, ax] = gyro[:, ax] - (coef[0] + coef[1] * x) - extra
    return b0, k, resid


def _quantum(x: Array) -> Array:
    """Per column, the smallest step between distinct values (the sensor's resolution; 1e-12 for none)."""
    out = np.full(x.shape[1], 1e-12)
    for j in range(x.shape[1]):
        d = np.diff(np.unique(x[:, j]))
        d = d[d > 0]
        if d.size:
            out[j] = max(float(d.min()), 1e-12)
    return out


def _rms_rate(t: Array, x: Array, block_s: float) -> float:
    """RMS rate of change of a slowly varying, quantised signal, from block means."""
    duration = float(t[-1] - t[0])
    block = max(block_s, duration / 200.0)
    n_blocks = int(duration // block)
    if n_blocks < 2:
        return abs(float(x[-1] - x[0])) / duration if duration > 0 else 0.0
    edges = t[0] + block * np.arange(n_blocks + 1)
    idx = np.searchsorted(t, edges)
    means = np.array([x[idx[i] : idx[i + 1]].mean() for i in range(n_blocks)])
    rates = np.diff(means) / block
    return float(np.sqrt(np.mean(rates**2)))


def tune(rec: Recording, settings: TuneSettings | None = None) -> TuneResult:
    """Fit the temperature model, noise, β and ζ to a stationary recording."""
    s = settings or TuneSettings()
    gyro = np.asarray(rec.gyro_rad_s, dtype=np.float64)
    accel = np.asarray(rec.accel_m_s2, dtype=np.float64)
    ok = np.all(np.isfinite(gyro), axis=1) & np.all(np.isfinite(accel), axis=1)
    ok &= np.linalg.norm(accel, axis=1) > 0
    dt = np.asarray(rec.dt_s, dtype=np.float64)
    t = rec.extra.get("time_s")
    t = (
        np.asarray(t, dtype=np.float64)
        if t is not None
        else np.cumsum(np.nan_to_num(dt)) - np.nan_to_num(dt[0])
    )
    temp_raw = rec.extra.get("temperature_c")
    temp = np.asarray(temp_raw, dtype=np.float64) if temp_raw is not None else None
    if temp is not None and not np.isfinite(temp).any():
        temp = None  # e.g. PX4's HIGHRES_IMU: no IMU temperature in the log (all NaN)
    if temp is not None:
        ok &= np.isfinite(temp)
    if ok.sum() < 100:
        raise DataError(f"{rec.name}: only {int(ok.sum())} usable samples; a stationary recording needs more")
    notes: list[str] = []
    use_temp = temp is not None and float(np.ptp(temp[ok])) >= s.min_temperature_span_c
    if temp is None:
        notes.append("no temperature in the recording: bias drift fitted against time, no temperature model")
    elif not use_temp:
        notes.append(
            f"temperature spread {np.ptp(temp[ok]):.2f} °C < {s.min_temperature_span_c} °C: "
            "no temperature model; bias drift fitted against time"
        )
    x_all = (temp if use_temp else t).astype(np.float64)  # type: ignore[union-attr]
    t0_c = float(np.mean(temp[ok])) if use_temp else float("nan")  # type: ignore[index]
    x0 = t0_c if use_temp else float(t[ok][0])
    truth = rec.extra.get("true_rate_rad_s")
    truth = np.asarray(truth, dtype=np.float64) if truth is not None else None
    if truth is not None:
        ok &= np.all(np.isfinite(truth), axis=1)
        notes.append(
            "the simulator's true body rates (SIMSTATE) were subtracted, with the gyro's scale/cross-axis "
            "error and filter lag fitted alongside, so a moving recording works too"
        )
    keep = ok.copy()
    dropped = 0
    # A gyro at rest sends integers (ArduPilot RAW_IMU: mrad/s): most samples sit on one or two levels, and
    # the MAD of such data can be far below one step.  No deviation within a step is an outlier.
    step = _quantum(gyro[ok])
    for _ in range(2):
        b0, k, resid = _bias_fit(x_all - x0, gyro, keep, truth, t)
        mad = np.median(np.abs(resid[keep] - np.median(resid[keep], axis=0)), axis=0) * 1.4826
        out = np.any(np.abs(resid) > s.outlier_sd * np.maximum(mad, step), axis=1) & ok
        new_keep = ok & ~out
        if np.array_equal(new_keep, keep) or new_keep.sum() < 100:
            break
        keep = new_keep
        dropped = int(out.sum())
    moving = np.any(np.abs(resid[ok]) > s.max_motion_rad_s, axis=1)
    if moving.mean() > 0.01:
        raise DataError(
            f"{rec.name}: {100 * moving.mean():.1f} % of the samples show a rate above "
            f"{math.degrees(s.max_motion_rad_s):.0f}°/s — `mavahrs tune` needs the vehicle at rest"
        )
    noise = resid[keep]
    noise_sd = noise.std(axis=0)
    if not np.all(noise_sd > 0):  # e.g. a simulator before arming: every reading the same, nothing to fit
        axes = "".join(a for a, sd in zip("xyz", noise_sd, strict=True) if not sd > 0)
        span = float(t[ok][-1] - t[ok][0])
        raise DataError(
            f"{rec.name}: not enough rest data to estimate the gyro's noise, bias and gains: the gyro's {axes} "
            f"reading{'s do' if len(axes) > 1 else ' does'} not change at all over the {int(keep.sum())} samples "
            f"({span:.1f} s) — a simulator before arming, or a log cut short? Record the IMU at rest for a "
            "minute or more"
        )
    noise_mean_abs = np.mean(np.abs(noise - noise.mean(axis=0)), axis=0)
    omega_beta = float(np.mean(noise_mean_abs))  # "mean zero-mean error of each axis"
    tk = t[keep]
    if use_temp:
        temp_rate = _rms_rate(tk, temp[keep], s.block_s)  # type: ignore[index]
        drift_rate_axes = np.abs(k) * temp_rate
        drift = np.zeros(3)
    else:
        temp_rate = 0.0
        drift_rate_axes = np.abs(k)
        drift = k.copy()
    omega_zeta = float(np.sqrt(np.mean(drift_rate_axes**2)))

    # ---- least squares, 004 eq. (5)
    accel_mean = accel[keep].mean(axis=0)
    mag = rec.mag_ut
    mag_ok = None
    if mag is not None:
        m = np.asarray(mag, dtype=np.float64)[keep]
        m = m[np.all(np.isfinite(m), axis=1) & (np.linalg.norm(m, axis=1) > 0)]
        if m.shape[0] > 10:
            mag_ok = m.mean(axis=0)
    q_rest = _rest_attitude(accel_mean, mag_ok)
    refs = [(np.array([0.0, 0.0, -1.0]), accel_mean / np.linalg.norm(accel_mean))]
    if mag_ok is not None:
        m_hat = mag_ok / np.linalg.norm(mag_ok)
        h = _rotate_to_body(conjugate(q_rest), m_hat)  # field in NED
        b = np.array([math.hypot(h[0], h[1]), 0.0, h[2]])  # Madgwick 2010, eq. (46)
        refs.append((b, m_hat))
    eps = 1e-3  # rad: small enough to be linear, large enough for the finite differences

    def perturbed_gradient(directions: Array) -> Array:
        n = np.linalg.norm(directions, axis=1, keepdims=True)
        unit = np.where(n > 0, directions / np.where(n > 0, n, 1.0), 0.0)
        qp = multiply(q_rest, from_rotation_vector(eps * unit))
        v = _gradient_direction(qp, refs)
        v[n[:, 0] == 0] = 0.0
        return v

    rng = np.random.default_rng(0)
    sel = np.flatnonzero(keep)
    if sel.size > 20000:  # the gain is a mean: 20 000 samples pin it to < 1 %
        sel = np.sort(rng.choice(sel, 20000, replace=False))
    theta = resid[sel] - noise.mean(axis=0)
    zeros = np.zeros((sel.size, 1))
    w_beta = 0.5 * multiply(q_rest, np.hstack([zeros, theta]))  # eq. (2): ½ q ⊗ [0, ϑ]
    v_beta = perturbed_gradient(theta)
    beta_terms = least_squares_terms(v_beta, w_beta)
    beta_ls = _ratio(beta_terms)

    # ζ: A_t = α(T_t) − α(T_start), its uncorrected integral sets the gradient direction
    order = np.flatnonzero(keep)
    dtk = np.diff(t[order], prepend=t[order][0])
    a_t = np.outer(x_all[order] - x_all[order][0], k)
    err = np.cumsum(a_t * dtk[:, None], axis=0)  # attitude error the drift accumulates, rad
    step = max(1, order.size // 20000)
    sub = np.arange(0, order.size, step)
    v_z = perturbed_gradient(err[sub])
    omega_eps = 2.0 * multiply(conjugate(q_rest), v_z)[:, 1:]  # eq. (47)
    u_t = np.cumsum(omega_eps * (dtk[sub] * step)[:, None], axis=0)  # eq. (48) without ζ
    zeta_terms = least_squares_terms(u_t, a_t[sub]) if np.any(a_t) else (0.0, 0.0)
    zeta_ls = _ratio(zeta_terms) if np.any(a_t) else 0.0

    dur = float(t[ok][-1] - t[ok][0])
    return TuneResult(
        name=rec.name,
        samples=int(keep.sum()),
        duration_s=dur,
        rate_hz=float((ok.sum() - 1) / dur) if dur > 0 else float("nan"),
        axes=9 if mag_ok is not None else 6,
        temperature_model=bool(use_temp),
        t0_c=t0_c,
        temperature_range_c=(
            (float(np.min(temp[ok])), float(np.max(temp[ok]))) if temp is not None else (math.nan, math.nan)
        ),
        b0_rad_s=tuple(float(v) for v in b0),  # type: ignore[arg-type]
        k_rad_s_per_c=tuple(float(v) for v in (k if use_temp else np.zeros(3))),  # type: ignore[arg-type]
        drift_rad_s2=tuple(float(v) for v in drift),  # type: ignore[arg-type]
        noise_sd_rad_s=tuple(float(v) for v in noise_sd),  # type: ignore[arg-type]
        noise_mean_abs_rad_s=tuple(float(v) for v in noise_mean_abs),  # type: ignore[arg-type]
        omega_beta_rad_s=omega_beta,
        omega_zeta_rad_s2=omega_zeta,
        temperature_rate_c_s=temp_rate,
        beta_spec=SPEC_FACTOR * omega_beta,
        zeta_spec=SPEC_FACTOR * omega_zeta,
        beta_ls=beta_ls,
        zeta_ls=float(zeta_ls),
        dropped_samples=dropped,
        notes=notes,
        beta_ls_terms=beta_terms,
        zeta_ls_terms=zeta_terms,
    )


def tune_file(
    path: Any,
    *,
    imu: str = "auto",
    start_s: float | None = None,
    end_s: float | None = None,
    settings: TuneSettings | None = None,
    source: tuple[int, int | None] | None = None,
) -> TuneResult:
    """:func:`tune` on a flight log (tlog, DataFlash, ULog: by content; the daemon's scaling and timing) or a CSV,
    cut to ``start_s``…``end_s``.

    ``source`` = (system, component or None): a tlog's IMU data from that sender only (``--source``).

    One task of a multi-recording fit (a module-level function: Dask sends it to its workers).
    """
    from pathlib import Path

    from mavahrs.evaluation.loaders import load_one
    from mavahrs.evaluation.tlogdata import cut_recording, load_tlog_recording

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(2, "no such file", str(p))
    from mavahrs.logs import sniff

    fmt = sniff(p)
    if fmt == "tlog" or (fmt is None and p.suffix.lower() == ".tlog"):
        rec = load_tlog_recording(p, imu=imu, reference=False, source=source)
    elif fmt is not None:  # DataFlash, ULog
        rec = load_one(p, imu=imu, reference=False)
    else:
        rec = load_one(p)
    return tune(cut_recording(rec, start_s, end_s), settings)


def combine(results: list[TuneResult], name: str = "") -> TuneResult:
    """One set of gains over several recordings (e.g. an airframe's last flights).

    The least-squares gains fit all the recordings' samples at once: their
    terms ``tr(VᵀW)`` and ``tr(VᵀV)`` are summed before the ratio (004,
    eq. (5)).  The spec-formula gains use the noise figures averaged with the
    samples as weights (ω̃_ζ as an RMS).  The gyro bias is per power-up, so no
    temperature model is combined: its per-recording fits are in each result.
    """
    if not results:
        raise DataError("no recordings to tune over")
    if len(results) == 1:
        return results[0]
    w = np.array([r.samples for r in results], dtype=np.float64)
    w /= w.sum()

    def mean3(attr: str) -> tuple[float, float, float]:
        return tuple(float(v) for v in np.average([getattr(r, attr) for r in results], axis=0, weights=w))  # type: ignore[return-value]

    beta_terms = (sum(r.beta_ls_terms[0] for r in results), sum(r.beta_ls_terms[1] for r in results))
    zeta_terms = (sum(r.zeta_ls_terms[0] for r in results), sum(r.zeta_ls_terms[1] for r in results))
    omega_beta = float(np.average([r.omega_beta_rad_s for r in results], weights=w))
    omega_zeta = float(np.sqrt(np.average([r.omega_zeta_rad_s2**2 for r in results], weights=w)))
    dur = sum(r.duration_s for r in results)
    samples = sum(r.samples for r in results)
    variances = np.average([np.square(r.noise_sd_rad_s) for r in results], axis=0, weights=w)
    # the bias's drift in time is fitted only where a recording has no temperature model (its slope in time)
    unmodelled = [k for k, r in enumerate(results) if not r.temperature_model]
    drift: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    if unmodelled:
        drift = tuple(float(v) for v in np.average([results[k].drift_rad_s2 for k in unmodelled], axis=0,
                                                     weights=w[unmodelled]))  # type: ignore[assignment]
    notes = [
        f"one set of gains over {len(results)} recordings ({', '.join(r.name for r in results)}): least-squares "
        "terms summed, noise figures averaged by samples; no temperature model (the bias differs per power-up)"
    ]
    return TuneResult(
        name=name or f"{len(results)} recordings",
        samples=samples,
        duration_s=dur,
        rate_hz=float(np.average([r.rate_hz for r in results], weights=w)),
        axes=min(r.axes for r in results),
        temperature_model=False,
        t0_c=math.nan,
        temperature_range_c=(
            min(r.temperature_range_c[0] for r in results),
            max(r.temperature_range_c[1] for r in results),
        ),
        b0_rad_s=mean3("b0_rad_s"),
        k_rad_s_per_c=(0.0, 0.0, 0.0),
        drift_rad_s2=drift,
        noise_sd_rad_s=tuple(float(v) for v in np.sqrt(variances)),  # type: ignore[arg-type]
        noise_mean_abs_rad_s=mean3("noise_mean_abs_rad_s"),
        omega_beta_rad_s=omega_beta,
        omega_zeta_rad_s2=omega_zeta,
        temperature_rate_c_s=float(np.average([r.temperature_rate_c_s for r in results], weights=w)),
        beta_spec=SPEC_FACTOR * omega_beta,
        zeta_spec=SPEC_FACTOR * omega_zeta,
        beta_ls=_ratio(beta_terms),
        zeta_ls=_ratio(zeta_terms) if zeta_terms[1] > 0 else 0.0,
        dropped_samples=sum(r.dropped_samples for r in results),
        notes=notes,
        beta_ls_terms=beta_terms,
        zeta_ls_terms=zeta_terms,
        recordings=sum(r.recordings for r in results),
    )
