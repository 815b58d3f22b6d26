"""MAVLink 2 signing: key files, signed links, rejection of unsigned/forged/replayed frames, pymavlink interop."""

from __future__ import annotations

import hashlib
import os
import stat

import pytest

from mavahrs.errors import ConfigError
from mavahrs.protocol.codec import MavCodec, mavlink
from mavahrs.protocol.signing import (
    NEW_STREAM_TOLERANCE_10US,
    SIGNING_EPOCH_UNIX_S,
    SignatureCheck,
    SignatureVerifier,
    key_from_passphrase,
    load_signing_key,
    parse_signing_key,
    signature_fields,
    signing_timestamp_10us,
)

KEY = hashlib.sha256(b"test key").digest()
OTHER = hashlib.sha256(b"another key").digest()
T0 = signing_timestamp_10us(1_750_000_000.0)


def _write(path, text: str, mode: int = 0o600):
    path.write_text(text)
    os.chmod(path, mode)
    return path


def _imu(codec: MavCodec, t: int) -> bytes:
    return codec.encode(codec.mav.raw_imu_encode(t, 0, 0, -1000, 0, 0, 0, 0, 0, 0))


def _pair(require: bool = True) -> tuple[MavCodec, MavCodec]:
    a, b = MavCodec(1, 1), MavCodec(2, 191)
    a.enable_signing(KEY, link_id=1, initial_timestamp_10us=T0, require_signing=require)
    b.enable_signing(KEY, link_id=2, initial_timestamp_10us=T0, require_signing=require)
    return a, b


# ---------------------------------------------------------------- keys
def test_hex_key_file(tmp_path):
    p = _write(tmp_path / "k", KEY.hex().upper() + "\n")
    assert load_signing_key(p) == KEY


def test_passphrase_key_file_is_mavproxy_sha256(tmp_path):
    p = _write(tmp_path / "k", "correct horse battery staple\n", 0o640)  # group-readable is allowed
    key = load_signing_key(p)
    assert key == hashlib.sha256(b"correct horse battery staple").digest()  # MAVProxy: sha256(passphrase)
    assert key == key_from_passphrase("correct horse battery staple") == parse_signing_key(" correct horse battery staple ")
    # 63 hex characters is a passphrase, not a key
    assert parse_signing_key("a" * 63) == hashlib.sha256(b"a" * 63).digest()


def test_world_readable_key_file_refused_without_showing_the_key(tmp_path):
    secret = "my secret passphrase"
    p = _write(tmp_path / "k", secret, 0o644)
    with pytest.raises(ConfigError) as exc:
        load_signing_key(p)
    msg = str(exc.value)
    assert "readable by every user" in msg and "chmod 600" in msg and "0644" in msg
    assert secret not in msg and hashlib.sha256(secret.encode()).hexdigest() not in msg


@pytest.mark.parametrize("content, match", [(None, "No such file"), ("", "empty"), ("   \n", "empty")])
def test_missing_or_empty_key_file(tmp_path, content, match):
    p = tmp_path / "k"
    if content is not None:
        _write(p, content)
    with pytest.raises(ConfigError, match=match):
        load_signing_key(p)


def test_key_file_must_be_a_regular_text_file(tmp_path):
    d = tmp_path / "dir"
    d.mkdir(mode=0o700)
    with pytest.raises(ConfigError, match="not a regular file"):
        load_signing_key(d)
    b = tmp_path / "bin"
    b.write_bytes(b"\xff\xfe\x00\x01")
    os.chmod(b, stat.S_IRUSR | stat.S_IWUSR)
    with pytest.raises(ConfigError, match="not text"):
        load_signing_key(b)


def test_codec_rejects_bad_keys_without_echoing_them():
    c = MavCodec()
    with pytest.raises(ConfigError, match="32 bytes"):
        c.enable_signing(b"short")
    with pytest.raises(ValueError):
        c.enable_signing(KEY, link_id=300)


def test_no_key_in_any_repr():
    a, _ = _pair()
    v = SignatureVerifier(KEY)
    for text in (repr(a), repr(a._signing), repr(v)):
        assert KEY.hex() not in text and repr(KEY) not in text


def test_signing_timestamp_units():
    assert signing_timestamp_10us(SIGNING_EPOCH_UNIX_S) == 0
    assert signing_timestamp_10us(SIGNING_EPOCH_UNIX_S + 1.5) == 150_000
    assert signing_timestamp_10us(0) == 0  # before 2015: clamped


# ---------------------------------------------------------------- links
def test_signed_link_end_to_end_both_directions():
    a, b = _pair()
    frames = [_imu(a, t) for t in range(5)]
    assert all(f[2] & 1 for f in frames)  # signed flag
    ts = [signature_fields(f)[1] for f in frames]
    assert ts == list(range(T0, T0 + 5))  # one tick per frame, from the caller's wall time
    assert [signature_fields(f)[0] for f in frames] == [1] * 5
    msgs = [m for f in frames for m in b.receive_datagram(f)]
    assert [m.time_usec for m in msgs] == [0, 1, 2, 3, 4] and all(m._signed and m._link_id == 1 for m in msgs)
    assert b.counters.signed_ok == 5 and b.counters.signing_rejected == 0
    reply = b.encode(b.mav.heartbeat_encode(18, 8, 0, 0, 4))
    assert [m.get_type() for m in a.receive_stream(reply)] == ["HEARTBEAT"]
    assert a.counters.signed_ok == 1


def test_unsigned_rejected_only_when_required():
    a, b = _pair(require=True)
    plain = MavCodec(1, 1)
    assert b.receive_datagram(_imu(plain, 1)) == []
    assert b.receive_datagram(plain.encode(plain.mav.heartbeat_encode(1, 3, 0, 0, 4), force_mavlink1=True)) == []
    assert b.counters.unsigned_rejected == 2 and b.counters.packets == 0
    _, lax = _pair(require=False)
    assert len(lax.receive_datagram(_imu(plain, 1))) == 1 and lax.counters.unsigned_rejected == 0


def test_wrong_key_and_tampered_frames_rejected():
    a, b = _pair()
    forger = MavCodec(1, 1)
    forger.enable_signing(OTHER, link_id=1, initial_timestamp_10us=T0 + 10**6)
    assert b.receive_datagram(_imu(forger, 1)) == []
    good = bytearray(_imu(a, 2))
    good[-1] ^= 0x01  # signature byte
    assert b.receive_datagram(bytes(good)) == []
    assert b.counters.bad_signature == 2
    # the forged far-future timestamp did not lock the genuine stream out (pymavlink's order would)
    assert [m.time_usec for m in b.receive_datagram(_imu(a, 3))] == [3]


def test_replayed_and_old_frames_rejected():
    a, b = _pair()
    f1, f2, f3 = (_imu(a, t) for t in (1, 2, 3))
    assert len(b.receive_datagram(f1)) == 1 and len(b.receive_datagram(f3)) == 1
    assert b.receive_datagram(f1) == []  # replay
    assert b.receive_datagram(f2) == []  # older than the newest on its stream
    assert b.counters.replayed == 2 and b.counters.duplicates == 0
    # a stream never seen, more than a minute older than our own time: rejected
    old = MavCodec(5, 1)
    old.enable_signing(KEY, link_id=0, initial_timestamp_10us=T0 - NEW_STREAM_TOLERANCE_10US - 1000)
    assert b.receive_datagram(_imu(old, 9)) == [] and b.counters.replayed == 3
    # within the tolerance: a new stream is accepted
    fresh = MavCodec(6, 1)
    fresh.enable_signing(KEY, link_id=0, initial_timestamp_10us=T0 - 100)
    assert len(b.receive_datagram(_imu(fresh, 9))) == 1


def test_streams_are_per_link_system_component():
    a, b = _pair()
    a2 = MavCodec(1, 1)
    a2.enable_signing(KEY, link_id=7, initial_timestamp_10us=T0)  # same source, another link, same timestamps
    assert len(b.receive_datagram(_imu(a, 1))) == 1
    assert len(b.receive_datagram(_imu(a2, 1))) == 1


def test_outgoing_timestamp_follows_wall_time_and_incoming():
    a, b = _pair()
    a.advance_signing_time(T0 + 500)
    assert a.signing_timestamp_10us == T0 + 500
    a.advance_signing_time(T0)  # never backwards
    assert signature_fields(_imu(a, 1))[1] == T0 + 500
    b.receive_datagram(_imu(a, 2))
    assert b.signing_timestamp_10us >= T0 + 501  # at least the newest valid timestamp seen
    b.disable_signing()
    assert not b.signing_enabled and not (_imu(b, 3)[2] & 1)


def test_mavlink1_frames_go_out_unsigned():
    a, _ = _pair()
    f = a.encode(a.mav.heartbeat_encode(18, 8, 0, 0, 4), force_mavlink1=True)
    assert f[0] == 0xFE


def test_verifier_api():
    a, _ = _pair()
    f = _imu(a, 1)
    v = SignatureVerifier(KEY, initial_timestamp_10us=T0)
    assert v.signature_ok(f)
    assert v.check(f, 0, len(f), 1, 1) is SignatureCheck.OK
    assert v.check(f, 0, len(f), 1, 1) is SignatureCheck.REPLAYED
    assert SignatureVerifier(OTHER).check(f, 0, len(f), 1, 1) is SignatureCheck.BAD_SIGNATURE


# ---------------------------------------------------------------- pymavlink interop
def _pymavlink_endpoint(mavutil, key: bytes, link_id: int):
    """A pymavlink endpoint set up exactly as ``mavfile.setup_signing`` does, capturing what it sends."""

    class Capture(mavutil.mavfile):
        def __init__(self) -> None:
            super().__init__(None, "capture", source_system=250, source_component=190, input=False)
            self.sent: list[bytes] = []

        def write(self, buf: bytes) -> None:
            self.sent.append(bytes(buf))

    ep = Capture()
    ep.setup_signing(key, sign_outgoing=True, link_id=link_id, initial_timestamp=T0 + 1000)
    return ep


def test_pymavlink_signed_frames_accepted_and_ours_verified_by_pymavlink(pymavlink_ref):
    from pymavlink import mavutil

    ep = _pymavlink_endpoint(mavutil, KEY, link_id=4)
    ep.mav.heartbeat_send(6, 8, 0, 0, 4)
    ep.mav.command_long_send(1, 191, 511, 0, 27, 2500, 0, 0, 0, 0, 0)
    _, b = _pair()
    msgs = [m for f in ep.sent for m in b.receive_datagram(f)]
    assert [m.get_type() for m in msgs] == ["HEARTBEAT", "COMMAND_LONG"]
    assert b.counters.signed_ok == 2 and all(m._link_id == 4 for m in msgs)
    # and the other way: pymavlink's parser with the key accepts our signed frames
    frames = [_imu(b, t) for t in (10, 11)]
    got = ep.mav.parse_buffer(b"".join(frames))
    assert [(m.get_type(), m.time_usec, m._signed) for m in got] == [("RAW_IMU", 10, True), ("RAW_IMU", 11, True)]
    assert ep.mav.signing.goodsig_count == 2
    # pymavlink with another key refuses them (as BAD_DATA with robust parsing)
    other = _pymavlink_endpoint(mavutil, OTHER, link_id=5)
    other.mav.robust_parsing = True
    bad = other.mav.parse_buffer(_imu(b, 12))
    assert [m.get_type() for m in bad] == ["BAD_DATA"] and other.mav.signing.badsig_count == 1
    # and our codec refuses pymavlink frames signed with another key
    other.mav.heartbeat_send(6, 8, 0, 0, 4)
    assert b.receive_datagram(other.sent[-1]) == [] and b.counters.bad_signature == 1
    assert isinstance(got[0], mavlink.MAVLink_raw_imu_message)
