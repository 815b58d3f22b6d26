"""The stream-request state machine: SET_MESSAGE_INTERVAL, DENIED step-down, fallback, re-requests, rate check."""

from __future__ import annotations

import logging

import pytest

from mavahrs.service.stream_requests import (
    MAV_DATA_STREAM_POSITION,
    MAV_DATA_STREAM_RAW_SENSORS,
    RequestDataStream,
    SetMessageInterval,
    StreamRequester,
    StreamRequestSettings,
)

S = 1_000_000
CMD = 511
ACCEPTED, TEMP_REJECTED, DENIED, UNSUPPORTED = 0, 1, 2, 3


def started(**kw):
    r = StreamRequester(StreamRequestSettings(**kw))
    r.want("RAW_IMU", 27, 400.0)
    r.start()
    return r


def only(reqs, kind):
    out = [q for q in reqs if isinstance(q, kind)]
    assert len(out) == 1, reqs
    return out[0]


def test_first_request_is_set_message_interval_at_the_wanted_rate():
    r = started()
    (q,) = r.poll(0)
    assert q == SetMessageInterval(27, "RAW_IMU", 2500, 0)
    assert r.poll(100_000) == []  # waiting for the ACK: nothing else in flight


def test_denied_steps_down_to_250_and_says_so_once_naming_sched_loop_rate():
    r = started()
    r.poll(0)
    r.on_statustext("Requested rate for message ID 27 too fast. Increase SCHED_LOOP_RATE", 10_000)
    r.on_command_ack(CMD, DENIED, 20_000)
    q = only(r.poll(30_000), SetMessageInterval)
    assert q.interval_us == 4000  # 250 Hz
    r.on_command_ack(CMD, ACCEPTED, 40_000)
    assert r.accepted_hz("RAW_IMU") == 250.0
    notes = r.drain_notices()
    assert len(notes) == 1
    level, text = notes[0]
    assert level == logging.WARNING and "400" in text and "250" in text and "SCHED_LOOP_RATE" in text
    # a later re-request that is accepted again does not repeat it
    q = only(r.poll(40_000 + 10 * S), SetMessageInterval)
    assert q.interval_us == 4000
    r.on_command_ack(CMD, ACCEPTED, 40_000 + 10 * S + 5000)
    assert not [t for _, t in r.drain_notices() if "SCHED_LOOP_RATE" in t]


def test_denied_all_the_way_down_falls_back():
    r = started(ladder_hz=(250.0,))
    r.poll(0)
    r.on_command_ack(CMD, DENIED, 1000)
    r.poll(2000)
    r.on_command_ack(CMD, DENIED, 3000)
    reqs = r.poll(4000)
    assert only(reqs, RequestDataStream) == RequestDataStream(MAV_DATA_STREAM_RAW_SENSORS, 400)


def test_periodic_re_request_at_the_accepted_rate():
    r = started(interval_s=10.0)
    r.poll(0)
    r.on_command_ack(CMD, ACCEPTED, 50_000)
    assert r.poll(5 * S) == []
    assert r.poll(10 * S) == []  # due 10 s after the ACK
    q = only(r.poll(10 * S + 50_000), SetMessageInterval)
    assert q.interval_us == 2500


def test_unanswered_commands_are_retried_then_fall_back_to_request_data_stream():
    r = started(ack_timeout_s=1.0, attempts=3)
    sent = [r.poll(0)]
    sent.append(r.poll(1 * S))
    sent.append(r.poll(2 * S))
    assert [only(s, SetMessageInterval).confirmation for s in sent] == [0, 1, 2]
    reqs = r.poll(3 * S)
    assert only(reqs, RequestDataStream) == RequestDataStream(MAV_DATA_STREAM_RAW_SENSORS, 400)
    only(reqs, SetMessageInterval)  # the command is still tried once per interval
    (level, text), = r.drain_notices()
    assert level == logging.WARNING and "REQUEST_DATA_STREAM" in text
    # the fallback request repeats every interval
    assert [q for q in r.poll(5 * S) if isinstance(q, RequestDataStream)] == []
    assert only(r.poll(13 * S), RequestDataStream).rate_hz == 400


def test_late_ack_in_fallback_returns_to_the_command():
    r = started(ack_timeout_s=1.0, attempts=1)
    r.poll(0)
    reqs = r.poll(1 * S)
    only(reqs, RequestDataStream)
    r.on_command_ack(CMD, ACCEPTED, 1 * S + 1000)  # answers the probe sent with it
    assert r.accepted_hz("RAW_IMU") == 400.0
    assert r.states(2 * S)[0].mode == "command"


def test_unsupported_falls_back_at_once():
    r = started()
    r.poll(0)
    r.on_command_ack(CMD, UNSUPPORTED, 1000)
    assert only(r.poll(2000), RequestDataStream).stream_id == MAV_DATA_STREAM_RAW_SENSORS


def test_temporarily_rejected_retries_same_rate():
    r = started(ack_timeout_s=0.5)
    r.poll(0)
    r.on_command_ack(CMD, TEMP_REJECTED, 1000)
    assert r.poll(200_000) == []
    assert only(r.poll(600_000), SetMessageInterval).interval_us == 2500


def test_one_command_in_flight_acks_matched_in_order():
    r = StreamRequester()
    r.want("RAW_IMU", 27, 400.0)
    r.want("GLOBAL_POSITION_INT", 33, 10.0, MAV_DATA_STREAM_POSITION)
    r.start()
    (a,) = r.poll(0)
    assert a.message == "RAW_IMU"
    r.on_command_ack(CMD, ACCEPTED, 1000)
    (b,) = r.poll(2000)
    assert b == SetMessageInterval(33, "GLOBAL_POSITION_INT", 100_000, 0)
    r.on_command_ack(CMD, ACCEPTED, 3000)
    assert r.accepted_hz("RAW_IMU") == 400.0 and r.accepted_hz("GLOBAL_POSITION_INT") == 10.0
    r.on_command_ack(CMD, ACCEPTED, 4000)  # unsolicited: ignored
    r.on_command_ack(400, ACCEPTED, 4000)  # another command's ACK: ignored
    assert r.acks == 2


def test_delivered_rate_far_below_accepted_is_warned():
    r = started(rate_grace_s=1.0)
    r.poll(0)
    r.on_command_ack(CMD, ACCEPTED, 1000)
    meter = r.meters["RAW_IMU"]
    for k in range(500):  # 100 Hz for 5 s
        meter.add(k * 10_000)
        if k % 50 == 0:
            r.poll(k * 10_000)
    notes = [t for _, t in r.drain_notices()]
    assert len(notes) == 1 and "arrives at 100 Hz" in notes[0] and "400 Hz" in notes[0]
    assert r.states(5 * S)[0].delivered_hz == pytest.approx(100.0, rel=0.05)


def test_full_rate_delivery_is_not_warned():
    r = started(rate_grace_s=1.0)
    r.poll(0)
    r.on_command_ack(CMD, ACCEPTED, 1000)
    for k in range(2000):
        r.meters["RAW_IMU"].add(k * 2500)
        if k % 100 == 0:
            r.poll(k * 2500)
    assert r.drain_notices() == []


def test_stop_and_restart_from_the_top():
    r = started()
    r.poll(0)
    r.on_command_ack(CMD, DENIED, 1000)
    r.poll(2000)
    r.on_command_ack(CMD, ACCEPTED, 3000)
    r.stop()
    assert r.poll(20 * S) == []
    r.start()  # reconnect / reboot: the autopilot forgot; try the full rate again
    assert only(r.poll(21 * S), SetMessageInterval).interval_us == 2500


def test_disabled_sends_nothing():
    r = started(enabled=False)
    assert r.poll(0) == [] and r.poll(100 * S) == []


def test_an_autopilot_that_never_answers_moves_every_message_to_data_streams_at_once():
    r = StreamRequester(StreamRequestSettings(ack_timeout_s=1.0, attempts=2))
    r.want("RAW_IMU", 27, 400.0)
    r.want("GLOBAL_POSITION_INT", 33, 10.0, MAV_DATA_STREAM_POSITION)
    r.start()
    r.poll(0)
    r.poll(1 * S)
    reqs = r.poll(2 * S)
    streams = sorted(q for q in reqs if isinstance(q, RequestDataStream))
    assert streams == [RequestDataStream(MAV_DATA_STREAM_RAW_SENSORS, 400), RequestDataStream(MAV_DATA_STREAM_POSITION, 10)]
    assert [s.mode for s in r.states(2 * S)] == ["data_stream", "data_stream"]
