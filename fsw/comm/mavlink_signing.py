"""MAVLink 2 message signing: the key file, and verification with replay protection.

Sans-I/O: the caller gives the raw frame and the current signing time; nothing here reads a
clock or a socket. (The key file is read by :func:`load_key`, called once at start-up.)

Verification follows the MAVLink 2 signing specification with one deliberate difference
from pymavlink's ``check_signature``: the stream timestamp is advanced only *after* the
signature is proven, so a forged frame with a huge timestamp cannot lock out the real
ground station. A frame is refused as

* ``UNSIGNED`` - no signature block (when signing is required);
* ``BAD_SIGNATURE`` - the SHA-256 signature does not match our key (wrong key, corrupted);
* ``REPLAY`` - a valid signature whose timestamp is not newer than the last one accepted on
  its stream ``(link_id, system, component)``;
* ``STALE`` - a valid signature opening a new stream with a timestamp more than
  ``max_age_s`` behind our signing time (spec: one minute);
* ``FUTURE`` - a valid signature whose timestamp is more than ``max_future_s`` ahead of our
  signing time. Accepting it would move the stream's window far ahead and lock out the
  stream's correctly timed commands as replays (a ground clock set days ahead did that);
  the window is not touched;
* ``NO_KEY`` - no key was loaded, so nothing can be authenticated.

The per-stream window (:attr:`SignatureVerifier.streams`) survives a restart through
``fsw.drivers.signing_store``: :attr:`SignatureVerifier.changed` says when to save it.
"""

from __future__ import annotations

import enum
import hashlib
import hmac
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path

from fsw.comm.mavlink_dialect import SIGNATURE_LEN, mavlink

KEY_LEN = 32


class KeyFileError(ValueError):
    """The signing key file is missing, unreadable or not a 32-byte key."""


class Verdict(enum.Enum):
    OK = "OK"
    UNSIGNED = "UNSIGNED"
    BAD_SIGNATURE = "BAD_SIGNATURE"
    REPLAY = "REPLAY"
    STALE = "STALE"
    NO_KEY = "NO_KEY"
    FUTURE = "FUTURE"


def parse_key(data: bytes) -> bytes:
    """A key from file contents: 64 hex digits (whitespace ignored) or 32 raw bytes."""
    text = data.strip()
    if len(text) == 2 * KEY_LEN:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            pass
    if len(data) == KEY_LEN:
        return bytes(data)
    raise KeyFileError(f"expected 64 hex digits or {KEY_LEN} raw bytes, got {len(data)} bytes "
                       "(make one with `safer-ground keygen FILE`)")


def load_key(path: str | Path) -> tuple[bytes, bool]:
    """Read a key file; returns ``(key, private)`` where ``private`` is False when group or
    others may read the file (the caller warns). Raises :class:`KeyFileError`."""
    p = Path(path)
    try:
        data = p.read_bytes()
        mode = p.stat().st_mode
    except FileNotFoundError:
        raise KeyFileError(f"{p}: key file not found") from None
    except IsADirectoryError:
        raise KeyFileError(f"{p}: is a directory, not a key file") from None
    except OSError as exc:
        raise KeyFileError(f"{p}: unreadable ({exc.strerror or exc})") from None
    try:
        key = parse_key(data)
    except KeyFileError as exc:
        raise KeyFileError(f"{p}: {exc}") from None
    return key, not (mode & (stat.S_IRWXG | stat.S_IRWXO))


def write_key(path: str | Path, key: bytes | None = None) -> bytes:
    """Create a key file readable by its owner only (``safer-ground keygen``); random unless
    ``key`` is given. Refuses to overwrite (FileExistsError)."""
    key = os.urandom(KEY_LEN) if key is None else key
    if len(key) != KEY_LEN:
        raise KeyFileError(f"a key has {KEY_LEN} bytes, got {len(key)}")
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(key.hex() + "\n")
    return key


def key_from_passphrase(passphrase: str) -> bytes:
    """MAVProxy's key for ``signing key PASSPHRASE``: SHA-256 of the passphrase."""
    return hashlib.sha256(passphrase.encode("utf-8")).digest()


def frame_signature(key: bytes, frame_without_sig: bytes) -> bytes:
    """The 6-byte signature: SHA-256(key + header + payload + CRC + link_id + timestamp)[:6]."""
    return hashlib.sha256(key + frame_without_sig).digest()[:6]


def signature_fields(frame: bytes) -> tuple[int, int] | None:
    """``(link_id, timestamp)`` of a signed MAVLink 2 frame, or None if it is not signed."""
    if len(frame) < 10 + 2 + SIGNATURE_LEN or frame[0] != mavlink.PROTOCOL_MARKER_V2:
        return None
    if not frame[2] & mavlink.MAVLINK_IFLAG_SIGNED:
        return None
    sig = frame[-SIGNATURE_LEN:]
    return sig[0], int.from_bytes(sig[1:7], "little")


@dataclass
class SignatureVerifier:
    """Checks signed uplink frames and keeps the per-stream timestamps (replay protection)."""

    key: bytes | None
    max_age_s: float = 60.0
    streams: dict[tuple[int, int, int], int] = field(default_factory=dict)
    counts: dict[Verdict, int] = field(default_factory=lambda: dict.fromkeys(Verdict, 0))
    max_streams: int = 64
    max_future_s: float = 60.0
    changed: bool = False  # the window moved since the owner last saved it (owner clears it)

    def verify(self, frame: bytes, system_id: int, component_id: int, now_ts: int) -> Verdict:
        """Judge one whole frame (as received); ``now_ts`` is our signing time (10 us units)."""
        verdict = self._verify(bytes(frame), system_id, component_id, now_ts)
        self.counts[verdict] += 1
        return verdict

    def _verify(self, frame: bytes, system_id: int, component_id: int, now_ts: int) -> Verdict:
        fields = signature_fields(frame)
        if fields is None:
            return Verdict.UNSIGNED
        if self.key is None:
            return Verdict.NO_KEY
        expected = frame_signature(self.key, frame[:-6])
        if not hmac.compare_digest(expected, frame[-6:]):
            return Verdict.BAD_SIGNATURE
        link_id, ts = fields
        if ts > now_ts + int(self.max_future_s * 100_000):
            return Verdict.FUTURE
        stream = (link_id, system_id, component_id)
        last = self.streams.get(stream)
        if last is not None and ts <= last:
            return Verdict.REPLAY
        if last is None and ts + int(self.max_age_s * 100_000) < now_ts:
            return Verdict.STALE
        if last is None and len(self.streams) >= self.max_streams:
            # bounded memory: forget the stream that has been quiet longest (oldest timestamp)
            del self.streams[min(self.streams, key=self.streams.__getitem__)]
        self.streams[stream] = ts
        self.changed = True
        return Verdict.OK

    def restore(self, streams: dict[tuple[int, int, int], int]) -> None:
        """Take a saved window (after a restart): a replay of an older command stays a REPLAY."""
        for stream, ts in streams.items():
            self.streams[stream] = max(ts, self.streams.get(stream, 0))

    def newest_timestamp(self) -> int:
        """Highest accepted timestamp (our signing time never falls behind it)."""
        return max(self.streams.values(), default=0)
