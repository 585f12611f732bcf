"""The gateway <-> robot frame protocol (docs/gateway-protocol.md): frames, bodies, a resynchronising decoder.

A frame on the serial/radio link, all integers little-endian::

    offset  size  field
    0       1     START   0xA5
    1       1     LEN     payload length, 0..MAX_PAYLOAD
    2       2     ROBOT   robot id (u16; 0xFFFF = every robot behind the port)
    4       2     SEQ     sequence number (u16): a request's own, an answer echoes its request's
    6       1     TYPE    frame type (``FrameType``)
    7       LEN   PAYLOAD the type's body (``BODIES``)
    7+LEN   2     CRC     CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over bytes 1 .. 6+LEN

Bodies are fixed layouts (``struct``), SI units as float32: metres, radians. ``encode_frame``
and ``FrameDecoder`` are symmetric; the decoder takes arbitrary byte chunks, skips garbage
before a START byte, rejects wrong lengths and bad CRCs (counting each) and resynchronises
by rescanning from the byte after a rejected START.
"""

from __future__ import annotations

import binascii
import enum
import math
import struct
from dataclasses import dataclass, field
from typing import Any, ClassVar

from runtime.errors import SwarmInputError

START = 0xA5
HEADER = struct.Struct("<BBHHB")  # START, LEN, ROBOT, SEQ, TYPE
CRC = struct.Struct("<H")
MAX_PAYLOAD = 250
OVERHEAD = HEADER.size + CRC.size  # 9 bytes around the payload
BROADCAST = 0xFFFF
MAX_ROBOT = 0xFFFE  # robot ids usable behind a port
MAX_TEXT = 200  # bytes of UTF-8 reason/error text
MAX_U32 = 0xFFFFFFFF  # steps, clocks and run epochs are u32
F32_MAX = 3.4028234663852886e38  # the largest finite float32
QUIET_S = 0.020  # a partial frame is given up after the line was quiet this long (s)


class FrameError(SwarmInputError):
    """A frame or body that cannot be built or parsed; the text says which field and why."""


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (check value of b"123456789": 0x29B1)."""
    return binascii.crc_hqx(data, 0xFFFF)


class FrameType(enum.IntEnum):
    """Frame types: 0x01-0x7F gateway -> robot (requests), 0x81-0xFF robot -> gateway (answers)."""

    COMMAND = 0x01  # MotionBody: turn, then drive
    OBSERVE = 0x02  # StepBody: report your neighbour observations of this step
    HEARTBEAT = 0x03  # HeartbeatBody: the gateway is alive
    ESTOP = 0x04  # EmptyBody: stop now and stay stopped (latched)
    RESET = 0x05  # EmptyBody: clear the emergency stop
    RUN = 0x06  # RunBody: a new run begins: forget the step memory of the last one
    ACCEPTED = 0x81  # StepBody: command valid, executing
    DONE = 0x82  # StepBody: command executed
    REFUSED = 0x83  # RefusalBody: command not executed, with a code and text
    OBSERVATION = 0x84  # ObservationBody: one part of the observation report of a step
    HEARTBEAT_ACK = 0x85  # HeartbeatBody: echo of a heartbeat
    ESTOPPED = 0x86  # EmptyBody: stopped (answer to ESTOP)
    RESET_ACK = 0x87  # EmptyBody: emergency stop cleared
    ERROR = 0x88  # ErrorBody: the robot could not parse or handle a request
    RUN_ACK = 0x89  # RunBody (echo): step memory cleared, the robot is in that run


class RefusalCode(enum.IntEnum):
    """Why a robot refused a command (REFUSED.code)."""

    LIMITS = 1  # outside the robot's own limits
    ESTOPPED = 2  # emergency stop is latched (RESET clears it)
    NO_HEARTBEAT = 3  # no heartbeat within the timeout: the robot stopped by itself
    BUSY = 4  # still executing another command
    OTHER = 255


class ErrorCode(enum.IntEnum):
    """ERROR.code."""

    BAD_BODY = 1  # a request whose payload does not fit its type
    UNKNOWN_TYPE = 2
    OTHER = 255


@dataclass(frozen=True, slots=True)
class EmptyBody:
    """No payload (ESTOP, RESET, ESTOPPED, RESET_ACK)."""

    FORMAT: ClassVar[struct.Struct] = struct.Struct("<")

    def pack(self) -> bytes:
        return b""

    @classmethod
    def unpack(cls, payload: bytes) -> EmptyBody:
        _exact(payload, 0, cls)
        return cls()


@dataclass(frozen=True, slots=True)
class StepBody:
    """``step`` (u32): the global step a request or answer is about (OBSERVE, ACCEPTED, DONE)."""

    step: int
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<I")

    def pack(self) -> bytes:
        return _pack(self.FORMAT, self, self.step)

    @classmethod
    def unpack(cls, payload: bytes) -> StepBody:
        return cls(*_unpack(cls, payload))


@dataclass(frozen=True, slots=True)
class MotionBody:
    """COMMAND: at ``step``, turn by ``turn_rad`` (counter-clockwise +), then drive ``drive_m`` (float32)."""

    step: int
    turn_rad: float
    drive_m: float
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<Iff")

    def pack(self) -> bytes:
        return _pack(self.FORMAT, self, self.step, self.turn_rad, self.drive_m)

    @classmethod
    def unpack(cls, payload: bytes) -> MotionBody:
        return cls(*_unpack(cls, payload))


@dataclass(frozen=True, slots=True)
class HeartbeatBody:
    """HEARTBEAT / HEARTBEAT_ACK: the gateway's clock in ms (u32, wraps), echoed by the robot."""

    time_ms: int
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<I")

    def pack(self) -> bytes:
        return _pack(self.FORMAT, self, self.time_ms & 0xFFFFFFFF)

    @classmethod
    def unpack(cls, payload: bytes) -> HeartbeatBody:
        return cls(*_unpack(cls, payload))


@dataclass(frozen=True, slots=True)
class RunBody:
    """RUN / RUN_ACK: ``epoch`` (u32, != 0) of the run the gateway begins; the robot echoes it."""

    epoch: int
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<I")

    def pack(self) -> bytes:
        return _pack(self.FORMAT, self, self.epoch)

    @classmethod
    def unpack(cls, payload: bytes) -> RunBody:
        return cls(*_unpack(cls, payload))


def fits_f32(value: float) -> bool:
    """Whether ``value`` is finite and stays finite as a float32 (|value| <= ``F32_MAX``)."""
    return math.isfinite(value) and abs(value) <= F32_MAX


def _text(payload: bytes, cls: type) -> str:
    try:
        return payload.decode("utf-8")
    except UnicodeDecodeError:
        raise FrameError(f"{cls.__name__}: text is not UTF-8") from None


@dataclass(frozen=True, slots=True)
class RefusalBody:
    """REFUSED: ``step`` (u32), ``code`` (u8, ``RefusalCode``), then UTF-8 ``reason`` to the end."""

    step: int
    code: int
    reason: str = ""
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<IB")

    def pack(self) -> bytes:
        return _pack(self.FORMAT, self, self.step, self.code) + _utf8(self.reason)

    @classmethod
    def unpack(cls, payload: bytes) -> RefusalBody:
        step, code = _unpack(cls, payload[: cls.FORMAT.size])
        return cls(step, code, _text(payload[cls.FORMAT.size:], cls))


@dataclass(frozen=True, slots=True)
class ErrorBody:
    """ERROR: ``code`` (u8, ``ErrorCode``), then UTF-8 ``text`` to the end."""

    code: int
    text: str = ""
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<B")

    def pack(self) -> bytes:
        return _pack(self.FORMAT, self, self.code) + _utf8(self.text)

    @classmethod
    def unpack(cls, payload: bytes) -> ErrorBody:
        (code,) = _unpack(cls, payload[: cls.FORMAT.size])
        return cls(code, _text(payload[cls.FORMAT.size:], cls))


ENTRY = struct.Struct("<Hff")  # neighbour id, range m, bearing rad
MAX_ENTRIES = (MAX_PAYLOAD - 10) // ENTRY.size  # 24 neighbours per OBSERVATION frame


@dataclass(frozen=True, slots=True)
class ObservationBody:
    """OBSERVATION part ``part`` of ``parts`` (0-based) of the report of ``step``.

    Header ``<IIBB``: step (u32), robot clock ``stamp_ms`` at sensing (u32, wraps; 0 if
    unknown), part (u8), parts (u8, >= 1); then ``entries``: (neighbour id u16, range m
    float32, bearing rad float32 in the body frame), at most ``MAX_ENTRIES`` per frame.
    """

    step: int
    stamp_ms: int
    part: int
    parts: int
    entries: tuple[tuple[int, float, float], ...] = field(default=())
    FORMAT: ClassVar[struct.Struct] = struct.Struct("<IIBB")

    def pack(self) -> bytes:
        if not 0 <= self.part < self.parts:
            raise FrameError(f"ObservationBody: part {self.part} is not in [0, parts={self.parts})")
        if len(self.entries) > MAX_ENTRIES:
            raise FrameError(f"ObservationBody: {len(self.entries)} entries, at most {MAX_ENTRIES} per frame")
        head = _pack(self.FORMAT, self, self.step, self.stamp_ms & 0xFFFFFFFF, self.part, self.parts)
        try:
            return head + b"".join(ENTRY.pack(*e) for e in self.entries)
        except struct.error as exc:
            raise FrameError(f"ObservationBody: bad entry ({exc})") from None

    @classmethod
    def unpack(cls, payload: bytes) -> ObservationBody:
        n = cls.FORMAT.size
        if len(payload) < n or (len(payload) - n) % ENTRY.size:
            raise FrameError(f"ObservationBody: {len(payload)} bytes is not {n} + k * {ENTRY.size}")
        step, stamp, part, parts = cls.FORMAT.unpack_from(payload)
        if not 0 <= part < parts:
            raise FrameError(f"ObservationBody: part {part} is not in [0, parts={parts})")
        entries = tuple(ENTRY.iter_unpack(payload[n:]))
        return cls(step, stamp, part, parts, entries)


def _utf8(text: str) -> bytes:
    """``text`` as UTF-8, cut to ``MAX_TEXT`` bytes without splitting a character."""
    return text.encode("utf-8")[:MAX_TEXT].decode("utf-8", "ignore").encode("utf-8")


def _pack(fmt: struct.Struct, body: object, *values: object) -> bytes:
    try:
        return fmt.pack(*values)
    except (struct.error, OverflowError) as exc:
        raise FrameError(f"{type(body).__name__}: {exc} (values {values})") from None


def _exact(payload: bytes, size: int, cls: type) -> None:
    if len(payload) != size:
        raise FrameError(f"{cls.__name__}: payload of {len(payload)} bytes, expected {size}")


def _unpack(cls: type[Body], payload: bytes) -> tuple[Any, ...]:
    _exact(payload, cls.FORMAT.size, cls)
    return cls.FORMAT.unpack(payload)


Body = EmptyBody | StepBody | MotionBody | HeartbeatBody | RefusalBody | ErrorBody | ObservationBody | RunBody

BODIES: dict[FrameType, type[Body]] = {
    FrameType.COMMAND: MotionBody,
    FrameType.OBSERVE: StepBody,
    FrameType.HEARTBEAT: HeartbeatBody,
    FrameType.ESTOP: EmptyBody,
    FrameType.RESET: EmptyBody,
    FrameType.RUN: RunBody,
    FrameType.ACCEPTED: StepBody,
    FrameType.DONE: StepBody,
    FrameType.REFUSED: RefusalBody,
    FrameType.OBSERVATION: ObservationBody,
    FrameType.HEARTBEAT_ACK: HeartbeatBody,
    FrameType.ESTOPPED: EmptyBody,
    FrameType.RESET_ACK: EmptyBody,
    FrameType.ERROR: ErrorBody,
    FrameType.RUN_ACK: RunBody,
}


@dataclass(frozen=True, slots=True)
class Frame:
    """One frame: ``robot`` (u16), ``seq`` (u16), ``type`` (``FrameType`` value), raw ``payload``."""

    robot: int
    seq: int
    type: int
    payload: bytes = b""

    def body(self) -> Body:
        """The payload parsed by its type's body class; ``FrameError`` if it does not fit."""
        try:
            cls = BODIES[FrameType(self.type)]
        except ValueError:
            raise FrameError(f"unknown frame type 0x{self.type:02X}") from None
        return cls.unpack(self.payload)

    @classmethod
    def of(cls, robot: int, seq: int, kind: FrameType, body: Body) -> Frame:
        """A frame carrying ``body`` (checked against ``kind``)."""
        if not isinstance(body, BODIES[kind]):
            raise FrameError(f"{kind.name} carries a {BODIES[kind].__name__}, not a {type(body).__name__}")
        return cls(robot, seq, int(kind), body.pack())


def encode_frame(frame: Frame) -> bytes:
    """The bytes of ``frame`` on the wire (START .. CRC)."""
    n = len(frame.payload)
    if n > MAX_PAYLOAD:
        raise FrameError(f"payload of {n} bytes, at most {MAX_PAYLOAD}")
    if not 0 <= frame.robot <= BROADCAST:
        raise FrameError(f"robot id {frame.robot} is outside [0, 0xFFFF]")
    if not 0 <= frame.seq <= 0xFFFF:
        raise FrameError(f"sequence number {frame.seq} is outside [0, 0xFFFF]")
    if not 0 <= frame.type <= 0xFF:
        raise FrameError(f"frame type {frame.type} is outside [0, 0xFF]")
    head = HEADER.pack(START, n, frame.robot, frame.seq, frame.type) + frame.payload
    return head + CRC.pack(binascii.crc_hqx(head[1:], 0xFFFF))


@dataclass
class DecoderStats:
    """What a ``FrameDecoder`` rejected: bytes skipped while hunting for START, bad lengths, bad CRCs."""

    frames: int = 0
    crc_errors: int = 0
    length_errors: int = 0
    skipped_bytes: int = 0


class FrameDecoder:
    """Frames from a byte stream: ``feed(chunk)`` returns every complete valid frame so far.

    Resynchronisation: bytes before a START are skipped; a START whose LEN exceeds
    ``MAX_PAYLOAD`` or whose CRC fails is dropped as one skipped byte and the scan goes on
    from the next byte, so a valid frame hidden behind noise is still found. An incomplete
    frame waits for more bytes (``pending`` of them are held). A corrupted LEN can promise
    up to 259 bytes that never come: ``receive``, for readers that poll the line, applies
    the protocol's quiet-line rule and gives up on such STARTs after ``QUIET_S`` of silence.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._last_byte = -math.inf
        self.stats = DecoderStats()

    def receive(self, data: bytes, now: float) -> list[Frame]:
        """``feed(data)`` for a read at ``now`` (monotonic s; ``data`` empty when the read timed out).

        When no byte came for ``QUIET_S`` and a partial frame is pending, every START still
        waiting is given up (``resync``) and what follows them is rescanned.
        """
        if data:
            self._last_byte = now
            return self.feed(data)
        frames: list[Frame] = []
        if self._buf and now - self._last_byte >= QUIET_S:
            while self._buf:
                frames += self.resync()
        return frames

    @property
    def pending(self) -> int:
        return len(self._buf)

    def resync(self) -> list[Frame]:
        """Drop the START the decoder is waiting on (counted as a length error) and rescan what follows."""
        if not self._buf:
            return []
        del self._buf[0]
        self.stats.length_errors += 1
        self.stats.skipped_bytes += 1
        return self.feed(b"")

    def feed(self, data: bytes) -> list[Frame]:
        buf = self._buf
        buf += data
        out: list[Frame] = []
        stats = self.stats
        i = 0
        end = len(buf)
        while True:
            j = buf.find(START, i)
            if j < 0:
                stats.skipped_bytes += end - i
                i = end
                break
            stats.skipped_bytes += j - i
            i = j
            if end - i < 2:
                break
            n = buf[i + 1]
            if n > MAX_PAYLOAD:
                stats.length_errors += 1
                stats.skipped_bytes += 1
                i += 1
                continue
            total = n + OVERHEAD
            if end - i < total:
                break
            crc_at = i + total - 2
            if binascii.crc_hqx(buf[i + 1:crc_at], 0xFFFF) != buf[crc_at] | (buf[crc_at + 1] << 8):
                stats.crc_errors += 1
                stats.skipped_bytes += 1
                i += 1
                continue
            _, _, robot, seq, kind = HEADER.unpack_from(buf, i)
            out.append(Frame(robot, seq, kind, bytes(buf[i + 7:crc_at])))
            i += total
        del buf[:i]
        stats.frames += len(out)
        return out
