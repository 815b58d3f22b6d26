r"""MAVLink 2 message signing: keys, timestamps and signature checks (sans-I/O).

A signed MAVLink 2 frame carries 13 more bytes after its CRC: a link id (1
byte), a timestamp (6 bytes, little-endian, 10 µs units since
2015-01-01 00:00 UTC) and the first 6 bytes of
``SHA-256(secret_key + frame[:-6])`` (MAVLink developer guide, "Message
signing").  A receiver accepts a signed frame when the signature matches its
key and the timestamp is newer than the last one accepted on the same
``(link id, system id, component id)`` stream; a stream it has not seen
before is accepted when its timestamp is at most one minute behind the
receiver's own timestamp (pymavlink's ``check_signature`` rule).

Unlike pymavlink, :class:`SignatureVerifier` checks the signature *before*
it touches the stream's timestamp, so a forged frame with a far-future
timestamp cannot lock out the genuine sender, and it tells a bad signature
from a replay (:class:`SignatureCheck`).

Keys (:func:`load_signing_key`): a file holding either 64 hexadecimal
characters (the 32-byte key itself) or a passphrase, whose key is
``SHA-256(passphrase)`` exactly as MAVProxy's ``signing setup PASSPHRASE``
derives it.  The file must not be readable by other users.  The key never
appears in a message, log line or ``repr``.

Outgoing signing is done by pymavlink's packer (``MAVLink.signing``), set up
by :meth:`mavahrs.protocol.codec.MavCodec.enable_signing`.  Time is never read
here: :func:`signing_timestamp_10us` converts a wall-clock time the caller
passes in.
"""

from __future__ import annotations

import enum
import hashlib
import hmac
import os
import stat
import string
from collections import OrderedDict

from mavahrs.errors import ConfigError

__all__ = [
    "KEY_LEN",
    "SIGNATURE_LEN",
    "SIGNING_EPOCH_UNIX_S",
    "NEW_STREAM_TOLERANCE_10US",
    "SignatureCheck",
    "SignatureVerifier",
    "key_from_passphrase",
    "parse_signing_key",
    "load_signing_key",
    "validate_key",
    "signing_timestamp_10us",
    "signature_fields",
]

KEY_LEN = 32
SIGNATURE_LEN = 13
#: 2015-01-01 00:00:00 UTC as Unix time, the origin of signing timestamps
SIGNING_EPOCH_UNIX_S = 1420070400
#: a new stream is accepted if its timestamp is at most this far behind ours (60 s, as pymavlink)
NEW_STREAM_TOLERANCE_10US = 6_000_000
_HEX = frozenset(string.hexdigits)


class SignatureCheck(enum.Enum):
    """Outcome of :meth:`SignatureVerifier.check`."""

    OK = "ok"
    BAD_SIGNATURE = "bad_signature"
    REPLAYED = "replayed"


def validate_key(key: bytes) -> bytes:
    """Return ``key`` as bytes if it is a 32-byte signing key, else raise ``ConfigError`` (without the key)."""
    if not isinstance(key, (bytes, bytearray)) or len(key) != KEY_LEN:
        got = f"{len(key)} bytes" if isinstance(key, (bytes, bytearray)) else type(key).__name__
        raise ConfigError(f"a MAVLink signing key must be {KEY_LEN} bytes, got {got}")
    return bytes(key)


def key_from_passphrase(passphrase: str) -> bytes:
    """The 32-byte key MAVProxy derives from a passphrase: SHA-256 of its bytes."""
    if not passphrase:
        raise ConfigError("an empty passphrase cannot be used as a signing key")
    return hashlib.sha256(passphrase.encode("utf-8")).digest()


def parse_signing_key(text: str) -> bytes:
    """Key from a key file's text: 64 hex characters → those bytes; anything else → passphrase.

    Surrounding whitespace (the trailing newline) is ignored.
    """
    s = text.strip()
    if len(s) == 2 * KEY_LEN and set(s) <= _HEX:
        return bytes.fromhex(s)
    return key_from_passphrase(s)


def load_signing_key(path: str | os.PathLike[str]) -> bytes:
    """Read a signing key file (64 hex characters or a passphrase).

    Raises:
        ConfigError: the file is missing, unreadable, empty, or readable by
            every user (a shared secret must not be; ``chmod 600 FILE``).
    """
    p = os.fspath(path)
    try:
        st = os.stat(p)
    except OSError as exc:
        raise ConfigError(f"signing key file {p}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(f"signing key file {p} is not a regular file")
    if st.st_mode & stat.S_IROTH:
        raise ConfigError(
            f"signing key file {p} is readable by every user (mode {stat.S_IMODE(st.st_mode):04o}); "
            f"refusing to use it: run 'chmod 600 {p}'"
        )
    try:
        with open(p, "rb") as f:
            raw = f.read(4096)
    except OSError as exc:
        raise ConfigError(f"signing key file {p}: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError(f"signing key file {p} is not text (64 hex characters or a passphrase)") from None
    if not text.strip():
        raise ConfigError(f"signing key file {p} is empty (put 64 hex characters or a passphrase in it)")
    return parse_signing_key(text)


def signing_timestamp_10us(unix_time_s: float) -> int:
    """Signing timestamp (10 µs units since 2015-01-01 UTC) for a Unix time the caller supplies."""
    return max(0, int((float(unix_time_s) - SIGNING_EPOCH_UNIX_S) * 100_000))


def signature_fields(frame: bytes | bytearray, start: int = 0, length: int | None = None) -> tuple[int, int]:
    """(link id, timestamp in 10 µs units) of the signed frame ``frame[start:start+length]``."""
    end = start + (len(frame) - start if length is None else length)
    link_id = frame[end - SIGNATURE_LEN]
    ts = int.from_bytes(frame[end - 12 : end - 6], "little")
    return link_id, ts


class SignatureVerifier:
    """Checks signed frames against one key, with per-stream replay protection.

    Args:
        key: the 32-byte secret.
        initial_timestamp_10us: our own notion of "now" in signing units; a
            stream seen for the first time must not be more than a minute older.
        max_streams: how many (link, system, component) streams to remember
            (least recently used forgotten first; only validly signed frames
            create entries, so only key holders can fill it).
    """

    __slots__ = ("_key", "_streams", "_max_streams", "timestamp", "last_timestamp")

    def __init__(self, key: bytes, initial_timestamp_10us: int = 0, max_streams: int = 1024) -> None:
        self._key = validate_key(key)
        self._streams: OrderedDict[tuple[int, int, int], int] = OrderedDict()
        self._max_streams = int(max_streams)
        self.timestamp = int(initial_timestamp_10us)
        self.last_timestamp = 0

    def __repr__(self) -> str:
        return f"<SignatureVerifier streams={len(self._streams)} key=***>"

    def advance(self, timestamp_10us: int) -> None:
        """Raise our own timestamp (wall time from the caller); never moves back."""
        self.timestamp = max(self.timestamp, int(timestamp_10us))

    def signature_ok(self, frame: bytes | bytearray, start: int = 0, length: int | None = None) -> bool:
        """Whether the 6-byte signature of the signed frame matches the key (no replay check)."""
        end = start + (len(frame) - start if length is None else length)
        h = hashlib.sha256(self._key)
        h.update(memoryview(frame)[start : end - 6])
        return hmac.compare_digest(h.digest()[:6], bytes(frame[end - 6 : end]))

    def check(
        self, frame: bytes | bytearray, start: int, length: int, system_id: int, component_id: int
    ) -> SignatureCheck:
        """Verify the signed frame ``frame[start:start+length]`` from ``(system_id, component_id)``."""
        if not self.signature_ok(frame, start, length):
            return SignatureCheck.BAD_SIGNATURE
        link_id, ts = signature_fields(frame, start, length)
        key = (link_id, system_id, component_id)
        last = self._streams.get(key)
        if last is not None:
            if ts <= last:
                return SignatureCheck.REPLAYED
            self._streams.move_to_end(key)
        elif ts + NEW_STREAM_TOLERANCE_10US < self.timestamp:
            return SignatureCheck.REPLAYED
        self._streams[key] = ts
        if len(self._streams) > self._max_streams:
            self._streams.popitem(last=False)
        self.timestamp = max(self.timestamp, ts)
        self.last_timestamp = ts
        return SignatureCheck.OK
