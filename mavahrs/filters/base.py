r"""The interface every attitude filter shares, and the one batch loop.

A filter is a *kernel* — ``step(state, params, row, out)`` on flat float64
arrays (see :mod:`mavahrs.filters.layout`) — wrapped by a small class that
packs its settings into ``params``, owns its ``state`` and exposes:

* ``update(gyro_rad_s, accel_m_s2, mag_ut=None, *, dt_s, velocity_ned_m_s=None)``
  → the current ``q_body_to_ned`` (per-sample path, used by the daemon);
* ``run(inputs)`` → one output row per input row (batch path, used by replay
  and evaluation): the *same* kernel in a compiled loop;
* ``state`` (read/write, a :class:`FilterState` copy), ``reset()`` and
  ``diagnostics`` (:class:`FilterDiagnostics` of the last sample).

The common prefix of ``state`` and ``params`` (attitude, bias, initialisation
flag, gain schedule) is handled here by :func:`begin_step` /
:func:`finish_step`, so each filter module holds only its own equations.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mavahrs.filters import gains as _g
from mavahrs.filters.gains import GainScheduleSettings, schedule_reset
from mavahrs.filters.initial import align_heading_to_field, initial_attitude
from mavahrs.filters.jit import bound_loop, kernel, loop_kernel, prange, pure_python
from mavahrs.filters.layout import (
    FLAG_ACCEL_INVALID,
    FLAG_DT_INVALID,
    FLAG_GYRO_INVALID,
    FLAG_HEADING_ALIGNED,
    FLAG_MAG_INVALID,
    FLAG_NOT_INITIALISED,
    FLAG_REINITIALISED,
    FLAG_STARTUP,
    IN_ACCEL,
    IN_CURRENT,
    IN_DT,
    IN_GYRO,
    IN_MAG,
    IN_VEL,
    IN_VEL_AGE,
    IN_WIDTH,
    OUT_ACCEL_WEIGHT,
    OUT_BIAS,
    OUT_FLAGS,
    OUT_GAIN,
    OUT_HEADING_SIGMA,
    OUT_MAG_WEIGHT,
    OUT_Q,
    OUT_WIDTH,
)

__all__ = [
    "FilterSettings",
    "FilterState",
    "FilterDiagnostics",
    "AttitudeFilter",
    "make_inputs",
    "run_rows",
    "run_many",
    "begin_step",
    "finish_step",
    "add_flag",
    "vector_ok",
    "S_Q",
    "S_BIAS",
    "S_INIT",
    "S_SCHED",
    "S_FILTER",
    "P_MAX_GAP",
    "P_SCHED",
    "P_FILTER",
]

Array = NDArray[np.float64]

# Common state prefix.
S_Q = 0  # q_body_to_ned (4)
S_BIAS = 4  # gyro bias estimate, rad/s (3)
S_INIT = 7  # 1.0 once initialised (_INIT_NO_HEADING: from an accelerometer sample without a magnetometer reading)
_INIT_NO_HEADING = 2.0  # S_INIT after a start without a magnetometer reading, till the first one sets the heading
S_SCHED = 8  # gain schedule state (gains.GS_LEN)
S_FILTER = S_SCHED + _g.GS_LEN  # first filter-specific state value

# Common params prefix.
P_MAX_GAP = 0
P_SCHED = 1  # gain schedule params (gains.GP_LEN)
P_FILTER = P_SCHED + _g.GP_LEN  # first filter-specific parameter


@dataclass(frozen=True)
class FilterSettings:
    """Settings every filter has.

    Attributes:
        max_gap_s: a time step longer than this (s) is a gap: the filter
            re-initialises from the next valid accelerometer (+ magnetometer)
            sample instead of integrating across it.
        schedule: the shared start-up / rejection gain schedule.
    """

    max_gap_s: float = 1.0
    schedule: GainScheduleSettings = field(default_factory=GainScheduleSettings)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.max_gap_s) and self.max_gap_s > 0):
            raise ValueError(f"max_gap_s must be a positive number of seconds, got {self.max_gap_s!r}")

    def common_params(self) -> Array:
        return np.concatenate([[self.max_gap_s], self.schedule.to_params()])


@dataclass
class FilterState:
    """A copy of a filter's evolving state.

    Attributes:
        q_body_to_ned: attitude, scalar first.
        gyro_bias_rad_s: gyro bias estimate, body axes.
        initialised: False until the first valid accelerometer sample.
        schedule: the gain schedule's state (``gains.GS_*`` order).
        internal: the filter's own state values (layout per filter).
    """

    q_body_to_ned: Array
    gyro_bias_rad_s: Array
    initialised: bool
    schedule: Array
    internal: Array


@dataclass(frozen=True)
class FilterDiagnostics:
    """What the filter did on the last sample.

    Attributes:
        gain: the correction gain in effect (after boost and weights).
        accel_weight: trust in the accelerometer, 0 (rejected) … 1.
        mag_weight: trust in the magnetometer, 0 … 1.
        accel_rejected: accel_weight < 0.5.
        mag_rejected: a magnetometer was given but mag_weight < 0.5.
        startup: still in the start-up convergence phase.
        gyro_bias_rad_s: bias estimate, body axes.
        flags: the ``layout.FLAG_*`` bit field.
    """

    gain: float
    accel_weight: float
    mag_weight: float
    accel_rejected: bool
    mag_rejected: bool
    startup: bool
    gyro_bias_rad_s: tuple[float, float, float]
    flags: int

    @classmethod
    def from_row(cls, out: Array) -> FilterDiagnostics:
        flags = int(out[OUT_FLAGS])
        return cls(
            gain=float(out[OUT_GAIN]),
            accel_weight=float(out[OUT_ACCEL_WEIGHT]),
            mag_weight=float(out[OUT_MAG_WEIGHT]),
            accel_rejected=bool(out[OUT_ACCEL_WEIGHT] < 0.5),
            mag_rejected=bool(not flags & FLAG_MAG_INVALID and out[OUT_MAG_WEIGHT] < 0.5),
            startup=bool(flags & FLAG_STARTUP),
            gyro_bias_rad_s=(float(out[OUT_BIAS]), float(out[OUT_BIAS + 1]), float(out[OUT_BIAS + 2])),
            flags=flags,
        )


# --------------------------------------------------------------------------- kernels


@kernel
def vector_ok(x, y, z):  # type: ignore[no-untyped-def]
    """A vector usable as a direction: finite and not zero."""
    n = x * x + y * y + z * z
    return math.isfinite(n) and n > 0.0


@kernel(inline=True)  # runs every sample, too large for LLVM to inline by itself
def begin_step(state, params, row, out):  # type: ignore[no-untyped-def]
    """Common start of every filter step.

    Checks the inputs, initialises from the first valid accelerometer (+
    magnetometer) sample, guards ``dt`` (≤ 0 or non-finite: skip; longer than
    ``max_gap_s``: re-initialise), and sets the flags.  Returns the ``dt`` to
    integrate over, or −1 when the filter has nothing more to do this sample
    (``out`` is then already complete).
    """
    flags = 0
    accel_ok = vector_ok(row[IN_ACCEL], row[IN_ACCEL + 1], row[IN_ACCEL + 2])
    mag_ok = vector_ok(row[IN_MAG], row[IN_MAG + 1], row[IN_MAG + 2])
    gyro_ok = (
        math.isfinite(row[IN_GYRO]) and math.isfinite(row[IN_GYRO + 1]) and math.isfinite(row[IN_GYRO + 2])
    )
    if not accel_ok:
        flags |= FLAG_ACCEL_INVALID
    if not mag_ok:
        flags |= FLAG_MAG_INVALID
    if not gyro_ok:
        flags |= FLAG_GYRO_INVALID
    dt = row[IN_DT]
    dt_ok = math.isfinite(dt) and dt > 0.0
    if not dt_ok:
        flags |= FLAG_DT_INVALID
    reinit = state[S_INIT] > 0.0 and dt_ok and dt > params[P_MAX_GAP] and accel_ok
    if reinit:
        flags |= FLAG_REINITIALISED
    if state[S_INIT] == 0.0 or reinit:
        if accel_ok:
            initial_attitude(
                row[IN_ACCEL], row[IN_ACCEL + 1], row[IN_ACCEL + 2],
                row[IN_MAG], row[IN_MAG + 1], row[IN_MAG + 2], mag_ok, state, S_Q,
            )  # fmt: skip
            # 2: started without a magnetometer reading, the heading an arbitrary 0 until one comes
            state[S_INIT] = 1.0 if mag_ok else _INIT_NO_HEADING
            schedule_reset(state[S_SCHED : S_SCHED + _g.GS_LEN], params[P_SCHED : P_SCHED + _g.GP_LEN])
            flags |= FLAG_STARTUP
        else:
            flags |= FLAG_NOT_INITIALISED
        out[OUT_FLAGS] = flags
        finish_step(state, out, 0.0, 0.0, 0.0)
        out[OUT_FLAGS] = flags
        return -1.0
    out[OUT_FLAGS] = flags
    if not dt_ok or not gyro_ok:
        finish_step(state, out, 0.0, 0.0, 0.0)
        return -1.0
    if dt > params[P_MAX_GAP]:
        dt = params[P_MAX_GAP]  # a gap with no accelerometer to restart from: clamp
    if state[S_INIT] == _INIT_NO_HEADING and mag_ok:
        # the first reading after a start without one sets the heading, as it would have at the start
        # (a filter's own corrections take tens of seconds from an arbitrary heading, or never: a
        # magnetometer model seeded from the data takes the start's heading for the field's north);
        # the filter sees FLAG_HEADING_ALIGNED and moves what it holds in NED with the attitude
        if math.isfinite(align_heading_to_field(row[IN_MAG], row[IN_MAG + 1], row[IN_MAG + 2], state, S_Q)):
            state[S_INIT] = 1.0
            out[OUT_FLAGS] = flags | FLAG_HEADING_ALIGNED
    return dt


@kernel
def finish_step(state, out, gain, accel_weight, mag_weight):  # type: ignore[no-untyped-def]
    """Normalise the attitude and write the common output row (flags already set)."""
    n = math.sqrt(state[0] * state[0] + state[1] * state[1] + state[2] * state[2] + state[3] * state[3])
    if not (n > 0.0 and math.isfinite(n)):
        state[0], state[1], state[2], state[3] = 1.0, 0.0, 0.0, 0.0
        n = 1.0
    inv_n = 1.0 / n
    for i in range(4):
        state[S_Q + i] *= inv_n
        out[OUT_Q + i] = state[S_Q + i]
    for i in range(3):
        out[OUT_BIAS + i] = state[S_BIAS + i]
    out[OUT_GAIN] = gain
    out[OUT_ACCEL_WEIGHT] = accel_weight
    out[OUT_MAG_WEIGHT] = mag_weight
    out[OUT_HEADING_SIGMA] = math.nan  # no covariance (the ESKF writes its own after this)


@kernel
def add_flag(out, flag):  # type: ignore[no-untyped-def]
    """Set a ``FLAG_*`` bit in the output row (flags are stored as a float)."""
    out[OUT_FLAGS] = float(int(out[OUT_FLAGS]) | flag)


@loop_kernel
def run_rows(step, state, params, inputs, outputs):  # type: ignore[no-untyped-def]
    """The batch path: apply ``step`` to every input row, in order."""
    for i in range(inputs.shape[0]):
        step(state, params, inputs[i], outputs[i])


#: the kernel called by the cached loops below; bound per filter by jit.bound_loop (never set here)
_STEP: Any = None


def _rows_loop(state, params, inputs, outputs):  # type: ignore[no-untyped-def]
    """``run_rows`` with the kernel bound as the global ``_STEP`` (cacheable; see jit.bound_loop)."""
    for i in range(inputs.shape[0]):
        _STEP(state, params, inputs[i], outputs[i])


def _many_loop(states, params, inputs, outs, q_out, stride):  # type: ignore[no-untyped-def]
    """``_run_many_rows`` with the kernel bound as the global ``_STEP`` (cacheable)."""
    for m in prange(states.shape[0]):
        state = states[m]
        par = params[m]
        out = outs[m]
        for i in range(inputs.shape[0]):
            _STEP(state, par, inputs[i], out)
            if i % stride == 0:
                k = i // stride
                for j in range(4):
                    q_out[m, k, j] = out[OUT_Q + j]


def _batch_loops(step: Any) -> tuple[Any, Any]:
    """(rows loop, many loop) for a kernel: cached specialisations, or the generic loops with it bound."""
    loops = getattr(step, "_mavahrs_batch_loops", None)
    if loops is None:
        py = getattr(step, "py_func", step)
        name = f"_batch_{py.__module__.rsplit('.', 1)[-1]}_{py.__name__}"
        rows = bound_loop(_rows_loop, f"{name}_rows", _STEP=step)
        many = bound_loop(_many_loop, f"{name}_many", parallel=True, _STEP=step)
        if rows is None or many is None:  # a kernel outside mavahrs/filters: the uncached generic loops

            def rows(state, params, inputs, outputs):  # type: ignore[no-untyped-def]
                run_rows(step, state, params, inputs, outputs)

            def many(states, params, inputs, outs, q_out, stride):  # type: ignore[no-untyped-def]
                _run_many_rows(step, states, params, inputs, outs, q_out, stride)

        loops = (rows, many)
        try:
            step._mavahrs_batch_loops = loops  # memo on the kernel object itself
        except AttributeError:  # pragma: no cover - a kernel that takes no attributes
            pass
    return loops


@loop_kernel(parallel=True)
def _run_many_rows(step, states, params, inputs, outs, q_out, stride):  # type: ignore[no-untyped-def]
    """``run_rows`` for M independent filters (``prange`` over them); keeps the quaternion of every
    ``stride``-th row.  ``outs`` (M, OUT_WIDTH) is each filter's output row (scratch, then the last)."""
    for m in prange(states.shape[0]):
        state = states[m]
        par = params[m]
        out = outs[m]
        for i in range(inputs.shape[0]):
            step(state, par, inputs[i], out)
            if i % stride == 0:
                k = i // stride
                for j in range(4):
                    q_out[m, k, j] = out[OUT_Q + j]


def run_many(filters: Sequence[AttitudeFilter], inputs: Array, *, stride: int = 1) -> Array:
    """Run M filters of one class over the same recording in parallel; return (M, N, 4) quaternions.

    For gain sweeps: build one filter per parameter set (e.g.
    ``[Madgwick(MadgwickSettings(beta_rad_s=b)) for b in betas]``); each
    continues from its current state, and its state (and ``diagnostics``)
    afterwards are those after the last row, as with
    :meth:`AttitudeFilter.run`.  The filters run on numba's thread pool
    (``NUMBA_NUM_THREADS`` bounds it).

    ``stride`` > 1 keeps only the attitude after rows 0, stride, 2·stride, …
    (shape (M, ⌈N/stride⌉, 4), the same as ``run_many(...)[:, ::stride]``):
    a 1000-point sweep over a 10-minute 400 Hz recording would otherwise
    return 7.7 GB.  Every row is still filtered.
    """
    if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) or stride < 1:
        raise ValueError(f"stride must be a positive integer, got {stride!r}")
    stride = int(stride)
    filters = list(filters)
    if not filters:
        return np.zeros((0, 0, 4))
    cls = type(filters[0])
    if any(type(f) is not cls for f in filters):
        raise TypeError("run_many needs filters of one class (one kernel)")
    inputs = np.ascontiguousarray(inputs, dtype=np.float64)
    if inputs.ndim != 2 or inputs.shape[1] != IN_WIDTH:
        raise ValueError(f"inputs must have shape (N, {IN_WIDTH}), got {inputs.shape}")
    n = inputs.shape[0]
    states = np.ascontiguousarray(np.stack([f._state for f in filters]))
    params = np.ascontiguousarray(np.stack([f._params for f in filters]))
    outs = np.ascontiguousarray(np.stack([f._out for f in filters]))
    q_out = np.zeros((len(filters), (n + stride - 1) // stride, 4))
    if n:
        if filters[0]._compiled:
            _batch_loops(filters[0]._step)[1](states, params, inputs, outs, q_out, stride)
        else:
            for m, f in enumerate(filters):
                for i in range(n):
                    f._kernel(states[m], params[m], inputs[i], outs[m])
                    if i % stride == 0:
                        q_out[m, i // stride] = outs[m, OUT_Q : OUT_Q + 4]
    for m, f in enumerate(filters):
        f._state[:] = states[m]
        f._out[:] = outs[m]
    return q_out


# --------------------------------------------------------------------------- class


def make_inputs(
    gyro_rad_s: ArrayLike,
    accel_m_s2: ArrayLike,
    mag_ut: ArrayLike | None = None,
    *,
    dt_s: ArrayLike,
    velocity_ned_m_s: ArrayLike | None = None,
    velocity_age_s: ArrayLike | None = None,
) -> Array:
    """Pack sensor arrays (N, 3) into kernel input rows (N, ``IN_WIDTH``).

    ``velocity_age_s`` (N,) fills ``IN_VEL_AGE``; without it the age is 0 where
    a velocity component is given (a fix taken at the sample's time) and NaN
    where the whole velocity is NaN.
    """
    gyro = np.atleast_2d(np.asarray(gyro_rad_s, dtype=np.float64))
    n = gyro.shape[0]
    rows = np.full((n, IN_WIDTH), np.nan)
    rows[:, IN_GYRO : IN_GYRO + 3] = gyro
    rows[:, IN_ACCEL : IN_ACCEL + 3] = np.atleast_2d(np.asarray(accel_m_s2, dtype=np.float64))
    if mag_ut is not None:
        rows[:, IN_MAG : IN_MAG + 3] = np.atleast_2d(np.asarray(mag_ut, dtype=np.float64))
    if velocity_ned_m_s is not None:
        rows[:, IN_VEL : IN_VEL + 3] = np.atleast_2d(np.asarray(velocity_ned_m_s, dtype=np.float64))
        if velocity_age_s is None:
            rows[:, IN_VEL_AGE] = np.where(np.isnan(rows[:, IN_VEL : IN_VEL + 3]).all(axis=1), np.nan, 0.0)
    if velocity_age_s is not None:
        rows[:, IN_VEL_AGE] = np.broadcast_to(np.asarray(velocity_age_s, dtype=np.float64), (n,))
    rows[:, IN_DT] = np.broadcast_to(np.asarray(dt_s, dtype=np.float64), (n,))
    return rows


class AttitudeFilter(ABC):
    """Base of all filters.  Subclasses set the class attributes and ``filter_params``."""

    #: registry name, e.g. ``"madgwick"``
    name: ClassVar[str]
    #: the settings dataclass (a subclass of :class:`FilterSettings`)
    settings_type: ClassVar[type[FilterSettings]]
    #: the compiled kernel ``step(state, params, row, out)``
    step: ClassVar[Any]
    #: number of filter-specific state values after ``S_FILTER``
    internal_len: ClassVar[int] = 0

    def __init__(self, settings: FilterSettings | None = None, *, compiled: bool = True) -> None:
        if settings is None:
            settings = self.settings_type()
        if not isinstance(settings, self.settings_type):
            raise TypeError(
                f"{self.name} filter needs {self.settings_type.__name__}, got {type(settings).__name__}"
            )
        self._settings = settings
        self._compiled = compiled
        self._params = np.ascontiguousarray(
            np.concatenate([settings.common_params(), self.filter_params(settings)])
        )
        self._state = np.zeros(S_FILTER + self.internal_len)
        self._row = np.zeros(IN_WIDTH)
        self._row[IN_CURRENT] = np.nan  # update() takes no current
        self._out = np.zeros(OUT_WIDTH)
        step = type(self).__dict__.get("step") or type(self).step  # unbound: dispatchers bind like methods
        self._step = step
        self._kernel = step if compiled else pure_python(step)  # the interpreter all the way down
        self.reset()

    # -- to implement ---------------------------------------------------------
    @classmethod
    @abstractmethod
    def filter_params(cls, settings: Any) -> Array:
        """The filter-specific parameter block, appended after ``P_FILTER``."""

    def initial_internal(self) -> Array:
        """Initial filter-specific state (zeros unless overridden)."""
        return np.zeros(self.internal_len)

    # -- public ---------------------------------------------------------------
    @property
    def settings(self) -> FilterSettings:
        return self._settings

    @property
    def params(self) -> Array:
        """The packed parameter vector (read-only copy), e.g. for sweeps."""
        return self._params.copy()

    def reset(self) -> None:
        """Forget everything: the next valid sample initialises the filter."""
        self._state[:] = 0.0
        self._state[S_Q] = 1.0
        self._state[S_FILTER:] = self.initial_internal()
        self._out[:] = 0.0
        self._out[OUT_Q] = 1.0
        self._out[OUT_FLAGS] = FLAG_NOT_INITIALISED

    @property
    def state(self) -> FilterState:
        s = self._state
        return FilterState(
            q_body_to_ned=s[S_Q : S_Q + 4].copy(),
            gyro_bias_rad_s=s[S_BIAS : S_BIAS + 3].copy(),
            initialised=bool(s[S_INIT] > 0),
            schedule=s[S_SCHED:S_FILTER].copy(),
            internal=s[S_FILTER:].copy(),
        )

    @state.setter
    def state(self, value: FilterState) -> None:
        s = np.zeros_like(self._state)
        s[S_Q : S_Q + 4] = value.q_body_to_ned
        s[S_BIAS : S_BIAS + 3] = value.gyro_bias_rad_s
        s[S_INIT] = 1.0 if value.initialised else 0.0
        s[S_SCHED:S_FILTER] = value.schedule
        s[S_FILTER:] = value.internal
        self._state[:] = s

    @property
    def raw_state(self) -> Array:
        """The flat state vector (a copy), as the kernels see it."""
        return self._state.copy()

    @property
    def diagnostics(self) -> FilterDiagnostics:
        return FilterDiagnostics.from_row(self._out)

    @property
    def q_body_to_ned(self) -> Array:
        return self._out[OUT_Q : OUT_Q + 4].copy()

    def set_mag_reference(self, norm_ut: float, dip_rad: float) -> None:
        """Give the magnetometer rejection its reference field, e.g. from the World Magnetic Model.

        The same as constructing with ``schedule.mag_reference_norm_ut`` /
        ``mag_reference_dip_rad``, but on a running filter: the schedule's
        current reference is replaced at once and re-initialisations keep it
        (``settings`` is updated to match).  ``norm_ut = 0`` returns to
        learning the reference from the data (from the next initialisation).
        """
        if not (math.isfinite(norm_ut) and norm_ut >= 0.0 and math.isfinite(dip_rad)):
            raise ValueError(f"magnetic reference needs norm_ut ≥ 0 and a finite dip, got {norm_ut!r}, {dip_rad!r}")
        from dataclasses import replace

        self._settings = replace(
            self._settings,
            schedule=replace(self._settings.schedule, mag_reference_norm_ut=norm_ut, mag_reference_dip_rad=dip_rad),
        )
        self._params[P_SCHED + _g.GP_MAG_REF_NORM] = norm_ut
        self._params[P_SCHED + _g.GP_MAG_REF_DIP] = dip_rad
        if norm_ut > 0.0 and self._state[S_INIT] > 0.0:
            self._state[S_SCHED + _g.GS_MAG_NORM] = norm_ut
            self._state[S_SCHED + _g.GS_MAG_DIP] = dip_rad

    def update(
        self,
        gyro_rad_s: ArrayLike,
        accel_m_s2: ArrayLike,
        mag_ut: ArrayLike | None = None,
        *,
        dt_s: float,
        velocity_ned_m_s: ArrayLike | None = None,
        velocity_age_s: float | None = None,
    ) -> Array:
        """Process one sample; return the new ``q_body_to_ned`` (a copy).

        ``velocity_age_s``: how old the velocity is at this sample's time, s
        (sample time − the fix's own time; None = not known).
        """
        row = self._row
        row[IN_DT] = dt_s
        row[IN_GYRO : IN_GYRO + 3] = gyro_rad_s
        row[IN_ACCEL : IN_ACCEL + 3] = accel_m_s2
        row[IN_MAG : IN_MAG + 3] = np.nan if mag_ut is None else mag_ut
        row[IN_VEL : IN_VEL + 3] = np.nan if velocity_ned_m_s is None else velocity_ned_m_s
        row[IN_VEL_AGE] = np.nan if velocity_ned_m_s is None or velocity_age_s is None else velocity_age_s
        self._kernel(self._state, self._params, row, self._out)
        return self._out[OUT_Q : OUT_Q + 4].copy()

    def warm_up(self) -> None:
        """Compile (or load from the disk cache) the per-sample kernel now, not on the first sample.

        Runs the kernel once on scratch copies: the filter's state is untouched.
        The daemon calls this before it starts serving, so the first live
        sample is not delayed by compilation.
        """
        row = np.zeros(IN_WIDTH)
        row[IN_DT] = 0.0025
        row[IN_ACCEL + 2] = -9.80665
        row[IN_MAG : IN_MAG + 3] = (20.0, 0.0, 40.0)
        row[IN_VEL : IN_VEL + 3] = np.nan
        row[IN_CURRENT] = np.nan
        state = self._state.copy()
        out = np.zeros(OUT_WIDTH)
        for _ in range(2):  # initialise, then one regular step
            self._kernel(state, self._params, row, out)

    def update_row(self, row: Array) -> Array:
        """Process one packed input row; return the filter's output row (not a copy).

        The allocation-free path for the live daemon.
        """
        self._kernel(self._state, self._params, row, self._out)
        return self._out

    def run(self, inputs: Array, outputs: Array | None = None) -> Array:
        """Process every row of ``inputs`` (N, IN_WIDTH); return outputs (N, OUT_WIDTH)."""
        inputs = np.ascontiguousarray(inputs, dtype=np.float64)
        if inputs.ndim != 2 or inputs.shape[1] != IN_WIDTH:
            raise ValueError(f"inputs must have shape (N, {IN_WIDTH}), got {inputs.shape}")
        if outputs is None:
            outputs = np.zeros((inputs.shape[0], OUT_WIDTH))
        if inputs.shape[0] == 0:
            return outputs
        if self._compiled:
            _batch_loops(self._step)[0](self._state, self._params, inputs, outputs)
        else:
            for i in range(inputs.shape[0]):
                self._kernel(self._state, self._params, inputs[i], outputs[i])
        self._out[:] = outputs[-1]
        return outputs
