"""CDR, as ROS 2 puts it on the wire: little-endian plain CDR (XCDR1) behind a 4-byte encapsulation header.

A ROS 2 payload is ``00 01 00 00`` (CDR_LE, no options) followed by the message's fields in order, each
primitive aligned to its own size counted from the end of the header; a string is a uint32 length (its
bytes + the terminating NUL), the bytes and the NUL; a sequence is a uint32 count and its elements; a
fixed array its elements alone. Only what the ``ros2`` node's messages need is here (pure Python, no I/O):
:class:`Writer` builds a payload, :class:`Reader` takes one apart and says which field is wrong
(:class:`CdrError`) — a payload never raises anything else.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

HEADER = b"\x00\x01\x00\x00"  # encapsulation kind CDR_LE (0x0001), options 0
_U32 = struct.Struct("<I")
_I32 = struct.Struct("<i")
_TIME = struct.Struct("<iI")
_F64 = struct.Struct("<d")
MAX_COUNT = 1 << 16  # a sequence or string longer than this is refused (a payload is never that large here)


class CdrError(ValueError):
    """A payload that is not the CDR of the expected message; the text names the field."""


def stamp(t: float) -> tuple[int, int]:
    """``t`` seconds as builtin_interfaces/Time (sec, nanosec), to the nearest nanosecond."""
    sec, nanosec = divmod(round(t * 1e9), 1_000_000_000)
    return int(sec), int(nanosec)


_STRINGS: dict[tuple[tuple[str, ...], int], bytes] = {}  # Writer.strings' bytes by (strings, start mod 4)


class Writer:
    """A payload built field by field (``bytes(writer)`` or :meth:`payload`: the whole of it)."""

    __slots__ = ("buf",)

    def __init__(self) -> None:
        self.buf = bytearray(HEADER)

    def _align(self, n: int) -> None:
        pad = -(len(self.buf) - 4) % n
        if pad:
            self.buf += b"\x00" * pad

    def u32(self, value: int) -> Writer:
        self._align(4)
        self.buf += _U32.pack(value)
        return self

    def time(self, sec: int, nanosec: int) -> Writer:
        """builtin_interfaces/Time: int32 sec, uint32 nanosec."""
        self._align(4)
        self.buf += _TIME.pack(sec, nanosec)
        return self

    def string(self, text: str) -> Writer:
        data = text.encode()
        self.u32(len(data) + 1)
        self.buf += data
        self.buf += b"\x00"
        return self

    def header(self, sec: int, nanosec: int, frame_id: str) -> Writer:
        """std_msgs/Header: stamp, frame_id."""
        return self.time(sec, nanosec).string(frame_id)

    def f64s(self, values: Sequence[float]) -> Writer:
        """A fixed array of float64 (or consecutive float64 fields: a Vector3, a Quaternion)."""
        self._align(8)
        self.buf += struct.pack(f"<{len(values)}d", *values)
        return self

    def f64_seq(self, values: Sequence[float]) -> Writer:
        self.u32(len(values))
        return self.f64s(values) if len(values) else self

    def strings(self, values: Sequence[str]) -> Writer:
        """A sequence of strings. Its bytes depend only on the strings and where it starts (mod 4): a tuple's
        (a JointState's constant names, every step) are kept, :data:`_STRINGS`."""
        key = (values, (len(self.buf) - 4) % 4) if isinstance(values, tuple) else None
        if key is not None and (done := _STRINGS.get(key)) is not None:
            self.buf += done
            return self
        start = len(self.buf)
        self.u32(len(values))
        for v in values:
            self.string(v)
        if key is not None and len(_STRINGS) < 64:
            _STRINGS[key] = bytes(self.buf[start:])
        return self

    def payload(self) -> bytes:
        return bytes(self.buf)


class Reader:
    """A payload read field by field; every read checks the bounds and raises :class:`CdrError` naming the
    field (``what`` is the message's name, for the text)."""

    __slots__ = ("data", "pos", "what")

    def __init__(self, payload: bytes, what: str) -> None:
        self.what = what
        if len(payload) < 4:
            raise CdrError(f"{what}: not CDR (a payload of {len(payload)} bytes has no encapsulation header)")
        if payload[:2] != HEADER[:2]:
            kind = payload[:2].hex(" ")
            raise CdrError(f"{what}: not little-endian CDR (encapsulation header {kind}, expected 00 01)")
        self.data = memoryview(payload)[4:]
        self.pos = 0

    def _take(self, n: int, align: int, field: str) -> int:
        start = self.pos + (-self.pos % align)
        if start + n > len(self.data):
            raise CdrError(f"{self.what}.{field}: the payload ends early (truncated or not this message)")
        self.pos = start + n
        return start

    def u32(self, field: str) -> int:
        return int(_U32.unpack_from(self.data, self._take(4, 4, field))[0])

    def count(self, field: str) -> int:
        n = self.u32(field)
        if n > MAX_COUNT:
            raise CdrError(f"{self.what}.{field}: a length of {n} (not this message)")
        return n

    def time(self, field: str) -> tuple[int, int]:
        sec, nanosec = _TIME.unpack_from(self.data, self._take(8, 4, field))
        if nanosec >= 1_000_000_000:
            raise CdrError(f"{self.what}.{field}.nanosec: {nanosec} is not below 1e9")
        return int(sec), int(nanosec)

    def string(self, field: str) -> str:
        n = self.count(field)
        if n == 0:
            raise CdrError(f"{self.what}.{field}: a string without its terminating NUL")
        at = self._take(n, 1, field)
        raw = bytes(self.data[at:at + n])
        if raw[-1] != 0:
            raise CdrError(f"{self.what}.{field}: a string without its terminating NUL")
        try:
            return raw[:-1].decode()
        except UnicodeDecodeError:
            raise CdrError(f"{self.what}.{field}: not UTF-8 text") from None

    def header(self, field: str = "header") -> tuple[int, int, str]:
        sec, nanosec = self.time(f"{field}.stamp")
        return sec, nanosec, self.string(f"{field}.frame_id")

    def f64s(self, n: int, field: str) -> tuple[float, ...]:
        if n == 0:
            return ()
        at = self._take(8 * n, 8, field)
        return struct.unpack_from(f"<{n}d", self.data, at)

    def f64_seq(self, field: str) -> tuple[float, ...]:
        return self.f64s(self.count(field), field)

    def strings(self, field: str) -> tuple[str, ...]:
        return tuple(self.string(f"{field}[{i}]") for i in range(self.count(field)))

    def end(self) -> None:
        """The message is read: nothing but alignment padding may follow."""
        if len(self.data) - self.pos > 7:
            raise CdrError(f"{self.what}: {len(self.data) - self.pos} bytes after the message's end "
                           "(not this message)")


def finite(values: Sequence[float], field: str, what: str) -> tuple[float, ...]:
    """``values``, or CdrError naming the first number that is not finite."""
    for i, v in enumerate(values):
        if not math.isfinite(v):
            raise CdrError(f"{what}.{field}[{i}]: {v} is not a finite number")
    return tuple(values)
