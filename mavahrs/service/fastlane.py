r"""The daemon's fast lane: answer a steady-state RAW_IMU datagram before the Python path has run.

Run once every 2.5 ms, the interpreter works on a cold cache: on the 2-core
development VM decoding a RAW_IMU datagram and handling it took 40 µs and
98 µs at p50 (5.5 µs and 14 µs in a tight loop), most of the daemon's
latency from receipt to the ``sendto`` of the attitude.  The fast lane does
the part that decides the answer in three compiled calls:

1. :func:`_parse`: the datagram starts with an unsigned MAVLink 2 RAW_IMU
   frame with a valid CRC from the autopilot (what follows it in the same
   datagram is handled after it, so cannot change its answer), its sample scales like
   :class:`mavahrs.sensors.scaling.Scaler` with nothing saturated or
   invalid, belongs to the IMU instance the selector feeds, and the timeline
   step (:func:`mavahrs.ingest.timeline.timeline_step`, the pipeline's own, on a
   copy of that instance's timeline state) calls it plainly ``ok``; with
   several instances, also before the selector's next evaluation (which may
   switch) is due; then the filter's input row is
   written as ``Pipeline._feed`` writes it and the filter state is copied;
2. the filter's own compiled step on that copy;
3. :func:`_encode`: the output-rate rule, the declination and the
   ATTITUDE_QUATERNION frame byte for byte as ``Pipeline._attitude_frames``
   builds it (our ids, the encoder's next sequence number).

The daemon sends that frame at once and then runs the ordinary path — decode,
``Pipeline.handle`` with every counter, meter, selector, timeline and the real
filter update — which builds the frame again.  The two must be identical; the
daemon then does not send it twice.  If they ever differ (or the ordinary path
sends nothing), the daemon logs it, counts it (``fast_lane_mismatches``),
sends the ordinary path's frames and switches the lane off for the rest of
the run: at most one frame the pipeline would not have sent can go out (never
seen in testing), and it is followed at once by the pipeline's own — or, when
datagrams had queued up and were answered as a chain (:meth:`FastLane.answer_queue`),
the frames of that one chain from its first wrong one on, each followed by the
pipeline's own when its turn comes.

The lane reads the pipeline's state from a small mirror (:meth:`FastLane.refresh`,
after each datagram, outside the latency window) and stands aside whenever
anything is not the steady state: another message type, MAVLink 1, signing,
a stream link (serial/TCP), a GNSS velocity waiting for the next row,
calibration, ATTITUDE output, a fail-over backlog, a start or reboot.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np

from mavahrs.filters.jit import kernel
from mavahrs.filters.layout import (
    FLAG_NOT_INITIALISED,
    IN_ACCEL,
    IN_CURRENT,
    IN_DT,
    IN_GYRO,
    IN_POS,
    IN_VEL,
    IN_VEL_AGE,
    IN_WIDTH,
    OUT_BIAS,
    OUT_FLAGS,
    OUT_Q,
    OUT_WIDTH,
)
from mavahrs.ingest.timeline import F_LEN as TL_F_LEN
from mavahrs.ingest.timeline import K_OK, NO_NOW, T_RAW_MAX, new_state, timeline_step
from mavahrs.protocol.codec import mavlink
from mavahrs.protocol.fast_tlog import _CRC_TABLE, _wire_dtype, _x25_crc
from mavahrs.sensors.current import CURRENT_STALE_S
from mavahrs.sensors.scaling import C_LEN, scale_int_row

__all__ = ["FastLane"]

_RAW_IMU = mavlink.MAVLink_raw_imu_message
_AQ = mavlink.MAVLink_attitude_quaternion_message
_RAW_WIRE = _wire_dtype(_RAW_IMU)
_RAW_LEN = _RAW_WIRE.itemsize  # 29
# payload offsets of the RAW_IMU fields (wire order: largest first)
_O_T, _O_XACC, _O_YACC, _O_ZACC = (_RAW_WIRE.fields[f][1] for f in ("time_usec", "xacc", "yacc", "zacc"))
_O_XGYRO, _O_YGYRO, _O_ZGYRO = (_RAW_WIRE.fields[f][1] for f in ("xgyro", "ygyro", "zgyro"))
_O_XMAG, _O_YMAG, _O_ZMAG, _O_ID = (_RAW_WIRE.fields[f][1] for f in ("xmag", "ymag", "zmag", "id"))

# integer mirror
I_ON, I_SYS, I_COMP, I_IMU, I_EVAL_DUE = range(5)
I_LAST_OUT_T, I_NEXT_OUT_T, I_HAVE_NEXT, I_PERIOD, I_TOL, I_OUR_SYS, I_OUR_COMP, I_SEQ = range(5, 13)
I_CHAIN = 13  # answers may be chained over queued datagrams (nothing but the attitude takes sequence numbers)
I_TL_LEN = 14  # length of the timeline state's int part
# then the selected instance's timeline state (int part: a copy of the pipeline's), then the copy the
# timeline step runs on
I_TL = 15
# float mirror: the scaling step's constants (sensors.scaling C_*), the declination, then the timeline
# state's float part and the copy the step runs on
F_DECL = C_LEN
F_TL = C_LEN + 1
F_LEN = F_TL + 2 * TL_F_LEN


_RAW_ID, _RAW_CRC = int(_RAW_IMU.id), int(_RAW_IMU.crc_extra)
_NO_LIMIT = 2**62
_AQ_ID, _AQ_CRC = int(_AQ.id), int(_AQ.crc_extra)


@kernel
def _payload_i16(data, plen, off):  # type: ignore[no-untyped-def]
    """The little-endian int16 at payload offset ``off`` (zero past the payload: MAVLink 2 trims zeros)."""
    lo = np.int64(data[10 + off]) if off < plen else np.int64(0)
    hi = np.int64(data[11 + off]) if off + 1 < plen else np.int64(0)
    v = lo | (hi << 8)
    return v - 65536 if v >= 32768 else v


@kernel
def _parse(data, icfg, fcfg, row, state, scratch):  # type: ignore[no-untyped-def]
    """The sample's time (µs) with ``row`` written and ``state`` copied to ``scratch``; −1: not for the lane."""
    n = len(data)
    if icfg[I_ON] == 0 or n < 12 or data[0] != 0xFD or data[2] != 0:  # MAVLink 2, unsigned
        return -1
    plen = np.int64(data[1])
    if n < plen + 12 or plen > _RAW_LEN:  # the datagram starts with one whole frame
        return -1
    if np.int64(data[7]) | (np.int64(data[8]) << 8) | (np.int64(data[9]) << 16) != _RAW_ID:
        return -1
    if np.int64(data[5]) != icfg[I_SYS] or np.int64(data[6]) != icfg[I_COMP]:
        return -1
    crc = _x25_crc(data, 1, 10 + plen, _RAW_CRC, _CRC_TABLE)
    if crc != (np.int64(data[10 + plen]) | (np.int64(data[11 + plen]) << 8)):
        return -1
    imu = np.int64(data[10 + _O_ID]) if _O_ID < plen else np.int64(0)
    if imu >= 16:
        imu = 0
    if imu != icfg[I_IMU]:
        return -1
    t = np.int64(0)
    for i in range(8):
        if _O_T + i < plen:
            t |= np.int64(data[10 + _O_T + i]) << (8 * i)
    if t < 0:
        return -1  # beyond int64: the Python path judges
    xa, ya, za = (
        _payload_i16(data, plen, _O_XACC),
        _payload_i16(data, plen, _O_YACC),
        _payload_i16(data, plen, _O_ZACC),
    )
    xg, yg, zg = (
        _payload_i16(data, plen, _O_XGYRO),
        _payload_i16(data, plen, _O_YGYRO),
        _payload_i16(data, plen, _O_ZGYRO),
    )
    xm, ym, zm = (
        _payload_i16(data, plen, _O_XMAG),
        _payload_i16(data, plen, _O_YMAG),
        _payload_i16(data, plen, _O_ZMAG),
    )
    # the scaling step (Scaler's own): anything saturated, invalid or all-zero (the selector's absent-instance
    # rule) takes the Python path; the gyro, accelerometer and magnetometer columns of the row are written
    if scale_int_row(xg, yg, zg, xa, ya, za, xm, ym, zm, fcfg, row) != 0:
        return -1
    # ImuSelector.observe: no evaluation due (its clock is the raw time)
    if t >= icfg[I_EVAL_DUE] or t > T_RAW_MAX:
        return -1
    # the timeline step on a copy of the stream's state, keyed by gyro and accelerometer as the pipeline
    # keys it: plainly "ok", or the Python path decides
    k = icfg[I_TL_LEN]
    tst = icfg[I_TL + k : I_TL + 2 * k]
    for i in range(k):  # (element by element: a whole-array copy needs numba's runtime)
        tst[i] = icfg[I_TL + i]
    tfs = fcfg[F_TL + TL_F_LEN : F_TL + 2 * TL_F_LEN]
    for i in range(TL_F_LEN):
        tfs[i] = fcfg[F_TL + i]
    kind, tt, dt, _mono = timeline_step(tst, tfs, t, NO_NOW, row[IN_GYRO], row[IN_GYRO + 1], row[IN_GYRO + 2],
                                        row[IN_ACCEL], row[IN_ACCEL + 1], row[IN_ACCEL + 2], 6)  # fmt: skip
    if kind != K_OK:
        return -1
    row[IN_DT] = dt
    row[IN_VEL] = row[IN_VEL + 1] = row[IN_VEL + 2] = row[IN_VEL_AGE] = np.nan
    row[IN_POS] = row[IN_POS + 1] = row[IN_POS + 2] = np.nan
    for i in range(state.shape[0]):
        scratch[i] = state[i]
    return tt


@kernel
def _encode(out, row, t, icfg, fcfg, f32, f32_bytes, frame):  # type: ignore[no-untyped-def]
    """Length of the ATTITUDE_QUATERNION frame written to ``frame`` for sample time ``t``; 0: none is due."""
    if int(out[OUT_FLAGS]) & FLAG_NOT_INITIALISED:
        return 0
    if t <= icfg[I_LAST_OUT_T]:
        return 0
    if icfg[I_PERIOD] > 0 and icfg[I_HAVE_NEXT] != 0 and t < icfg[I_NEXT_OUT_T] - icfg[I_TOL]:
        return 0
    qw, qx, qy, qz = out[OUT_Q], out[OUT_Q + 1], out[OUT_Q + 2], out[OUT_Q + 3]
    dec = fcfg[F_DECL]
    if dec != 0.0:  # geomag.apply_declination_wxyz
        c = math.cos(0.5 * dec)
        s = math.sin(0.5 * dec)
        qw, qx, qy, qz = c * qw - s * qz, c * qx - s * qy, c * qy + s * qx, c * qz + s * qw
    f32[0], f32[1], f32[2], f32[3] = qw, qx, qy, qz
    f32[4] = row[IN_GYRO] - out[OUT_BIAS]
    f32[5] = row[IN_GYRO + 1] - out[OUT_BIAS + 1]
    f32[6] = row[IN_GYRO + 2] - out[OUT_BIAS + 2]
    t_ms = (t // 1000) & 0xFFFFFFFF
    for i in range(4):
        frame[10 + i] = (t_ms >> (8 * i)) & 0xFF
    for i in range(28):
        frame[14 + i] = f32_bytes[i]
    plen = 32
    while plen > 1 and frame[10 + plen - 1] == 0:  # MAVLink 2 truncates trailing zero bytes (keeps one)
        plen -= 1
    frame[0] = 0xFD
    frame[1] = plen
    frame[2] = 0
    frame[3] = 0
    frame[4] = icfg[I_SEQ]
    frame[5] = icfg[I_OUR_SYS]
    frame[6] = icfg[I_OUR_COMP]
    frame[7] = _AQ_ID & 0xFF
    frame[8] = (_AQ_ID >> 8) & 0xFF
    frame[9] = _AQ_ID >> 16
    crc = _x25_crc(frame, 1, 10 + plen, _AQ_CRC, _CRC_TABLE)
    frame[10 + plen] = crc & 0xFF
    frame[11 + plen] = crc >> 8
    return 12 + plen


class FastLane:
    """The compiled answer to steady-state RAW_IMU datagrams for one :class:`Pipeline` (see the module doc)."""

    def __init__(self, pipeline: Any, receive_codec: Any = None) -> None:
        self.pipeline = pipeline
        self._rx = receive_codec  # the master link's decoder: signed input needs its checks
        f = pipeline.filter
        self._step = getattr(f, "_kernel", None)
        self._state = getattr(f, "_state", None)
        self._params = getattr(f, "_params", None)
        self.usable = self._step is not None and isinstance(self._state, np.ndarray)
        tl_len = new_state(pipeline.settings.timeline)[0].shape[0]
        self.icfg = np.zeros(I_TL + 2 * tl_len, np.int64)
        self.icfg[I_TL_LEN] = tl_len
        self.fcfg = np.zeros(F_LEN)
        self._row = np.full(IN_WIDTH, np.nan)
        self._scratch = np.zeros(self._state.shape[0] if self.usable else 1)
        self._out = np.zeros(OUT_WIDTH)
        self._f32 = np.zeros(7, np.float32)
        self._f32_bytes = self._f32.view(np.uint8)
        self._frame = np.zeros(64, np.uint8)
        if self.usable:  # compile (or load) the kernels now, not on the first sample
            _parse(b"\0" * 12, self.icfg, self.fcfg, self._row, self._state, self._scratch)
            _encode(self._out, self._row, 0, self.icfg, self.fcfg, self._f32, self._f32_bytes, self._frame)

    def answer(self, data: bytes) -> bytes | None:
        """The ATTITUDE_QUATERNION frame for ``data``, or None: the ordinary path decides."""
        if self.icfg[I_ON] == 0 or type(data) is not bytes:  # (one compiled signature: bytes)
            return None
        t = _parse(data, self.icfg, self.fcfg, self._row, self._state, self._scratch)
        if t < 0:
            return None
        self._step(self._scratch, self._params, self._row, self._out)
        n = _encode(self._out, self._row, t, self.icfg, self.fcfg, self._f32, self._f32_bytes, self._frame)
        if n == 0:
            return None
        return self._frame[:n].tobytes()

    def answer_queue(self, datas: Iterable[bytes]) -> list[bytes | None]:
        """Chained answers for datagrams queued together (a stall delayed them): one per datagram taken.

        The first is answered as by :meth:`answer`; each next one from the
        state the previous answer left in the scratch copy, with the mirror
        advanced the way the pipeline will advance it (the timeline's last
        time, the output-rate rule, the sequence number).  Entries are the
        frame, or None where the filter stepped but no output was due.  The
        chain ends before the first datagram the lane does not take, and
        after one that holds more than the RAW_IMU frame (what follows the
        frame may change the pipeline's state).  The mirror is restored; the
        daemon confirms every answer with the Python path as usual, so a
        chain that went wrong is caught at its first wrong frame (and the
        frames after it in the chain have gone out too).
        """
        icfg = self.icfg
        taken: list[bytes | None] = []
        if icfg[I_ON] == 0 or icfg[I_CHAIN] == 0:
            return taken
        saved, saved_f = icfg.copy(), self.fcfg.copy()
        source = self._state
        try:
            for data in datas:
                if type(data) is not bytes:
                    break
                t = _parse(data, icfg, self.fcfg, self._row, source, self._scratch)
                if t < 0:
                    break
                self._step(self._scratch, self._params, self._row, self._out)
                n = _encode(self._out, self._row, t, icfg, self.fcfg, self._f32, self._f32_bytes, self._frame)
                taken.append(self._frame[:n].tobytes() if n else None)
                if len(data) != data[1] + 12:
                    break
                source = self._scratch  # the next sample continues from this one
                _advance(icfg, self.fcfg, t, n > 0)
        finally:
            icfg[:] = saved
            self.fcfg[:] = saved_f
        return taken

    def disable(self) -> None:
        self.usable = False
        self.icfg[I_ON] = 0

    def refresh(self) -> None:
        """Mirror the pipeline's state for the next datagram (off unless it is the steady state)."""
        icfg, fcfg = self.icfg, self.fcfg
        icfg[I_ON] = 0
        if not self.usable:
            return
        p = self.pipeline
        src, scaler, sel = p._source, p._scaler, p._selector
        imu = sel.selected
        if src is None or scaler is None or imu is None or p.sample_hook is not None:
            return
        if not p._fast_encode or p._mav.signing.sign_outgoing or p.settings.send_attitude_euler:
            return
        if not p._to_outputs:  # out_identity "none" (or a separate vehicle without a system id of its own)
            return
        if self._rx is not None and getattr(self._rx, "_signing", None) is not None:
            return
        ms = scaler.profile.messages.get("RAW_IMU")
        inst_source = sel.source_of(imu)
        tl = p._timelines.get(imu)
        cal = p._calibrators.get("RAW_IMU")
        if (
            ms is None
            or not ms.integer_fields
            or ms.time_to_us != 1
            or inst_source is None
            or tl is None
            or cal is None
        ):
            return
        if inst_source != "RAW_IMU" or sel.is_absent(imu) or p._backlog.get(imu) or cal.active:
            return
        if p._last_fed_imu != imu or p._last_fed_t is None or tl.st.shape[0] != icfg[I_TL_LEN]:
            return
        if p._vel is not None:
            return
        # the battery current the pipeline puts in every sample's row (the magnetometer model's motor field):
        # the same here, held while it stays fresh; about to go stale, the Python path decides
        current_us = p._current_us
        current = math.nan
        if current_us is not None:
            left_s = CURRENT_STALE_S - (p._last_now_us - current_us) * 1e-6
            if abs(left_s) < 1.0:
                return
            if left_s > 0.0:
                current = p._current_a
        self._row[IN_CURRENT] = current
        fcfg[:C_LEN] = scaler.scale_constants(ms)
        fcfg[F_DECL] = p._decl.declination_rad
        icfg[I_SYS], icfg[I_COMP], icfg[I_IMU] = src[0], src[1], imu
        k = tl.st.shape[0]  # the instance's timeline state, for the step to run on a copy of
        icfg[I_TL : I_TL + k] = tl.st
        fcfg[F_TL : F_TL + TL_F_LEN] = tl.fs
        if sel.n_instances() == 1 or sel.settings.fixed is not None:
            icfg[I_EVAL_DUE] = _NO_LIMIT  # one instance, or a fixed one: no evaluation can change the choice
        else:
            icfg[I_EVAL_DUE] = sel.next_evaluation_us  # a re-evaluation may switch: the Python path
        icfg[I_LAST_OUT_T] = p._last_out_t
        icfg[I_HAVE_NEXT] = p._next_out_t is not None
        icfg[I_NEXT_OUT_T] = p._next_out_t or 0
        icfg[I_PERIOD], icfg[I_TOL] = p._out_period_us, p._out_tol_us
        mav = p._mav
        icfg[I_OUR_SYS], icfg[I_OUR_COMP], icfg[I_SEQ] = mav.srcSystem, mav.srcComponent, mav.seq
        # Chaining predicts the sequence numbers: nothing else may take one meanwhile.  The monitor
        # sends a STATUSTEXT after an attitude only to resolve an autopilot attitude it holds, and
        # those arrive in other messages, which end a chain.
        icfg[I_CHAIN] = not p._monitor_on or not p._monitor._pending
        icfg[I_ON] = 1


def _advance(icfg: np.ndarray, fcfg: np.ndarray, t: int, sent: bool) -> None:
    """The mirror after a sample at time ``t`` was fed (``sent``: its attitude went out): as ``Pipeline._feed``."""
    k = int(icfg[I_TL_LEN])  # the timeline state the step left in the copy is the stream's now
    icfg[I_TL : I_TL + k] = icfg[I_TL + k : I_TL + 2 * k]
    fcfg[F_TL : F_TL + TL_F_LEN] = fcfg[F_TL + TL_F_LEN : F_TL + 2 * TL_F_LEN]
    if not sent:
        return
    icfg[I_SEQ] = (int(icfg[I_SEQ]) + 1) & 0xFF
    period = int(icfg[I_PERIOD])
    if period:
        nxt = (int(icfg[I_NEXT_OUT_T]) if icfg[I_HAVE_NEXT] else t) + period
        icfg[I_NEXT_OUT_T] = nxt if nxt > t else t + period
        icfg[I_HAVE_NEXT] = 1
    icfg[I_LAST_OUT_T] = t
