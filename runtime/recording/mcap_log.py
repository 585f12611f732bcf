"""MCAP recording of a run: every Zenoh message of ``swarm/<run>/**``, bytes unchanged (docs/recording.md).

Layout: one channel per key (topic = the Zenoh key, message encoding ``msgpack``); one
``jsonschema`` schema per message type (name = the type, data = ``json_schema(cls)``),
shared by every channel of that type; keys without a message type get schema id 0.
Unless ``foxglove=False``, derived channels are written too, each derived message right after
the raw one it comes from, message encoding ``json`` with a ``jsonschema`` schema: the Foxglove
3D scenes (``runtime.recording.foxglove_scene``: ``/foxglove/estimated``, ``/foxglove/true``,
``/foxglove/desired``, schema ``foxglove.SceneUpdate``) and the plottable channels
(``runtime.recording.plot_channels``: ``/robot/<id>/estimate``, ``/robot/<id>/truth``,
``/robot/<id>/error``, ``/swarm/error``, ``/swarm/plan``, ``/swarm/event``) that Foxglove's
Plot panel and PlotJuggler read; the raw channels are unchanged (same topics, schemas,
payloads, times and sequence numbers).
Metadata record ``run`` (string -> string; structured values JSON-encoded) is written
first, ``recorder`` (message counts, clean stop) at ``close()``. Chunks are zstd-compressed,
at most ``CHUNK_BYTES`` uncompressed, and a chunk is closed at least every ``FLUSH_S``
seconds (``mcap.writer.Writer.flush``), so a recorder killed by SIGKILL loses about the
last ``FLUSH_S`` seconds of messages, but never a ``Checkpoint``: one closes its chunk at once and
is synced to the disk (``os.fsync``) before ``checkpoints`` counts it, so a coordinator that waits
for it (``wait_checkpoints``) can be resumed from its recording after a SIGKILL or a host reboot
(``swarm coordinator --resume``); the file then has no summary and ``read_messages``,
``recording_info`` and ``recover`` read it with the stream reader up to the last complete record.

Reading never trusts the file: the record framing is checked first, reads are bounded by
the file size, chunk CRCs are validated, and every problem becomes a ``SwarmInputError``
naming the file, the offset and what is wrong.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import platform
import queue
import struct
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from importlib import metadata as _pkg_metadata
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, cast

import msgpack
from mcap.exceptions import EndOfFile, McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from runtime.errors import OptionError, RecordingError, SwarmInputError

try:
    from zstandard import ZstdError as _ZstdError
except ImportError:  # mcap's zstd support is optional; without it nothing raises this
    class _ZstdError(Exception):  # type: ignore[no-redef]  # the stand-in of the optional import
        pass
from runtime.recording.foxglove_scene import (
    DERIVED_TYPES,
    MESSAGE_ENCODING as DERIVED_ENCODING,
    SCENE_UPDATE_SCHEMA_BYTES,
    SCHEMA_NAME as DERIVED_SCHEMA,
    TOPIC_PREFIX as DERIVED_PREFIX,
    SceneDeriver,
    metadata_radius,
)
from runtime.recording.plot_channels import DERIVED_TYPES as PLOT_TYPES, SCHEMA_BYTES as PLOT_SCHEMAS, PlotDeriver, is_plot_topic
from runtime.wire.keys import KeyspaceError, run_wildcard, validate_run
from runtime.wire.messages import MessageError, decode, json_schema, type_for_key

if TYPE_CHECKING:
    from runtime.wire.messages import Message as WireMessage
    from runtime.wire.transport import ZenohSettings

CHUNK_BYTES = 64 * 1024  # uncompressed bytes after which a chunk is closed
FLUSH_S = 0.25  # a chunk is closed (and the file flushed) at least this often while messages arrive
MESSAGE_ENCODING = "msgpack"
SCHEMA_ENCODING = "jsonschema"
PROFILE = ""  # no MCAP profile (the well-known ones are ROS)
MAGIC = b"\x89MCAP0\r\n"
STOP_DRAIN_S = 0.2  # s without a message after SIGINT/SIGTERM before ``swarm record`` closes its file (``drain``)
DRAIN_LIMIT = 10  # a drain waits at most this many times its quiet time (a run still publishing does not hold the stop)
MAX_RECORD_BYTES = 2**31  # a record claiming more is treated as corruption, not as a truncated tail
_KNOWN_OPCODES = {int(op) for op in Opcode}
# What mcap and its decompressors raise on damaged data (zstandard.ZstdError is a plain Exception,
# lz4 raises RuntimeError); never SwarmInputError, which is raised as it is.
_READ_ERRORS = (McapError, EndOfFile, ValueError, struct.error, KeyError, IndexError, UnicodeDecodeError,
                MemoryError, RuntimeError, _ZstdError)


def _version(dist: str) -> str:
    try:
        return _pkg_metadata.version(dist)
    except _pkg_metadata.PackageNotFoundError:
        return "unknown"


def float_platform() -> str:
    """What decides the last bits of floating-point results here: numpy's and scipy's builds, the CPU's SIMD
    extensions numpy dispatches to and the kernels their OpenBLAS libraries chose for this CPU.

    numpy's vectorised functions (AVX-512 vs AVX2 paths) and the BLAS kernels bundled with numpy
    and scipy differ in the last bits between CPUs, so ``swarm replay --check`` is exact only where
    this string is the same. OpenBLAS picks its kernels by CPU model, not by the SIMD extensions
    alone (two AVX-512 CPUs may run its SkylakeX or its Haswell kernels), so each library's kernel
    name is part of the string: numpy's, scipy's and, where the ``cholmod`` extra is installed, cvxopt's (the
    localizers' sparse factorization), each loaded here so that every process names the same libraries whatever
    it has loaded so far.
    """
    import numpy as np  # noqa: PLC0415 - numpy is loaded by every caller anyway
    import scipy.linalg  # noqa: F401, PLC0415 - loads scipy's BLAS, so that its kernels are listed
    from threadpoolctl import threadpool_info  # noqa: PLC0415

    with contextlib.suppress(ImportError):
        import cvxopt  # noqa: F401, PLC0415 - the cholmod extra's BLAS (coordinator.localization.sparse_lm)

    simd = np.show_config(mode="dicts").get("SIMD Extensions", {})
    blas = sorted({f"{info.get('internal_api')} {info.get('architecture') or '?'}" for info in threadpool_info()
                   if info.get("user_api") == "blas"})
    return (f"numpy {np.__version__}, scipy {_version('scipy')}, {platform.machine()} "
            f"{'+'.join(simd.get('found', [])) or 'baseline'}, {' + '.join(blas) or 'no BLAS'}")


def software_versions() -> dict[str, str]:
    """Versions of python, numpy, zenoh, mcap, msgpack and this package, and the floating-point platform."""
    return {
        "python": platform.python_version(),
        "numpy": _version("numpy"),
        "zenoh": _version("eclipse-zenoh"),
        "mcap": _version("mcap"),
        "msgpack": _version("msgpack"),
        "inchworm-swarm": _version("inchworm-swarm"),
        "float_platform": float_platform(),
    }


def _metadata_map(values: dict[str, Any]) -> dict[str, str]:
    """A string -> string map: strings as they are, anything else JSON-encoded."""
    out: dict[str, str] = {}
    for k, v in values.items():
        out[str(k)] = v if isinstance(v, str) else json.dumps(v, sort_keys=True, default=str)
    return out


def _metadata_values(data: dict[str, str]) -> dict[str, Any]:
    """The inverse of ``_metadata_map`` as far as possible: JSON values decoded, other strings kept."""
    out: dict[str, Any] = {}
    for k, v in data.items():
        try:
            out[k] = json.loads(v)
        except (TypeError, ValueError):
            out[k] = v
    return out


def peek_stamp(payload: bytes) -> int | None:
    """``stamp_ns`` (ns) of an encoded message without validating the rest; None if absent or malformed."""
    try:
        obj = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    except (ValueError, TypeError, RecursionError, msgpack.UnpackException):
        return None
    stamp = obj.get("stamp_ns") if isinstance(obj, dict) else None
    return stamp if isinstance(stamp, int) and not isinstance(stamp, bool) and stamp >= 0 else None


class McapRecorder:
    """Writes ``(key, payload, publish_time_ns, log_time_ns)`` messages to an MCAP file.

    ``write`` is thread-safe and cheap (it queues); a writer thread owns the file. Use as a
    context manager or call ``close()``, which drains the queue and finishes the file
    (summary and indexes). ``metadata`` is stored as the ``run`` metadata record together
    with the run id and ``software_versions()``.

    ``foxglove`` (default True): also write the derived scene and plot channels
    (module docstring); the desired positions need ``metadata["trajectory"]`` (the
    trajectory JSON object). Derivation errors never stop the recording (counted in
    ``derived_errors``).

    A write error (disk full, file size limit, device gone) stops the writing, never the caller:
    ``error`` holds it, ``on_error(error)`` is called once from the writer thread, every message
    from then on is counted in ``dropped`` and not written, and ``close()`` finishes the file as far
    as it can (what reached the disk stays readable: ``recover``), then raises ``RecordingFailed``.
    """

    def __init__(self, path: str | os.PathLike[str], run: str, metadata: dict[str, Any] | None = None, *,
                 chunk_bytes: int = CHUNK_BYTES, flush_s: float = FLUSH_S, foxglove: bool = True,
                 on_error: Callable[[BaseException], object] | None = None) -> None:
        self.path = Path(path)
        self.run = validate_run(run)
        self.flush_s = float(flush_s)
        self.foxglove = bool(foxglove)
        trajectory = (metadata or {}).get("trajectory")
        self._deriver = SceneDeriver(trajectory, metadata_radius(metadata)) if self.foxglove else None
        self._plotter = PlotDeriver(trajectory) if self.foxglove else None
        self._derived_types: dict[str, bool] = {}  # key -> whether its type feeds the derived channels
        self._derived_channels: dict[str, int] = {}
        self._derived_schemas: dict[str, int] = {}
        self._derived_counts: dict[str, int] = {}
        self.derived_errors = 0
        if self.path.parent and not self.path.parent.exists():
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.path, "wb")
        self._writer = Writer(self._file, chunk_size=chunk_bytes, compression=CompressionType.ZSTD)
        self._writer.start(profile=PROFILE, library=f"inchworm-swarm {_version('inchworm-swarm')} / mcap-python {_version('mcap')}")
        run_meta = {"run": self.run, "created_ns": time.time_ns(), "versions": software_versions(), **(metadata or {})}
        self._writer.add_metadata("run", _metadata_map(run_meta))
        self._writer.flush()
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._typed: set[str] = set()
        self._counts: dict[str, int] = {}
        self._bad: dict[str, int] = {}
        self._lock = threading.Lock()
        self._queue: queue.SimpleQueue[tuple[str, bytes, int | None, int] | None] = queue.SimpleQueue()
        self._closed = False
        self._error: BaseException | None = None
        self.dropped = 0  # messages not written after a write error
        self.on_error = on_error
        self.checkpoints = 0  # Checkpoint messages on the disk (chunk closed, file synced)
        self._durable = threading.Condition()
        self._thread = threading.Thread(target=self._loop, name="mcap-recorder", daemon=True)
        self._thread.start()

    # -- producer side (any thread) --
    def write(self, key: str, payload: bytes, publish_time_ns: int | None = None, log_time_ns: int | None = None) -> None:
        """Queue one message; ``log_time_ns`` defaults to now, ``publish_time_ns`` to the message's ``stamp_ns``."""
        if self._closed:
            raise RecordingError(f"recorder of {self.path} is closed")
        if self._error is not None:
            with self._lock:
                self.dropped += 1
            return
        log_time = time.time_ns() if log_time_ns is None else int(log_time_ns)
        self._queue.put((str(key), bytes(payload), publish_time_ns, log_time))

    @property
    def error(self) -> BaseException | None:
        """The write error that stopped the recording, or None."""
        return self._error

    @property
    def count(self) -> int:
        """Messages written to the file so far (queued ones not included)."""
        with self._lock:
            return sum(self._counts.values())

    def counts(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)

    def derived_counts(self) -> dict[str, int]:
        """Per derived topic, messages written so far."""
        with self._lock:
            return dict(self._derived_counts)

    def bad_counts(self) -> dict[str, int]:
        """Per key, messages of a typed key that are malformed (no msgpack map with a stamp, or, for the keys
        the Foxglove views derive from, not valid); recorded anyway. ``swarm info`` validates every message."""
        with self._lock:
            return dict(self._bad)

    # -- writer thread --
    def _channel(self, key: str) -> int:
        channel_id = self._channels.get(key)
        if channel_id is None:
            schema_id = 0
            try:
                cls = type_for_key(key)
            except KeyspaceError:
                cls = None
            if cls is not None:
                schema_id = self._schemas.get(cls.TYPE, 0)
                if not schema_id:
                    schema_id = self._writer.register_schema(cls.TYPE, SCHEMA_ENCODING, json.dumps(json_schema(cls)).encode())
                    self._schemas[cls.TYPE] = schema_id
            channel_id = self._writer.register_channel(key, MESSAGE_ENCODING, schema_id)
            self._channels[key] = channel_id
            if schema_id:
                self._typed.add(key)
            self._derived_types[key] = cls is not None and issubclass(cls, DERIVED_TYPES + PLOT_TYPES)
        return channel_id

    def _write_now(self, key: str, payload: bytes, publish_time: int | None, log_time: int) -> None:
        channel_id = self._channel(key)
        bad = False
        msg = None
        derive = self._deriver is not None and self._derived_types[key]
        if derive:  # the derived views need the validated message
            try:
                msg = decode(payload, key=key)
            except MessageError:
                bad = key in self._typed
        if publish_time is None:
            # Only the stamp is needed: a cheap peek; the full validation of every message is swarm info's.
            stamp = msg.stamp_ns if msg is not None else (None if derive else peek_stamp(payload))
            bad = bad or (stamp is None and not derive and key in self._typed)
            publish_time = log_time if stamp is None else stamp
        with self._lock:
            self._counts[key] = self._counts.get(key, 0) + 1
            seq = self._counts[key]
            if bad:
                self._bad[key] = self._bad.get(key, 0) + 1
        self._writer.add_message(channel_id, log_time, payload, int(publish_time), sequence=seq & 0xFFFFFFFF)
        if derive and msg is not None:
            self._write_derived(msg, log_time)

    def _write_derived(self, msg: WireMessage, log_time: int) -> None:
        assert self._deriver is not None and self._plotter is not None  # foxglove recordings only
        try:
            derived = [(topic, DERIVED_SCHEMA, data) for topic, data in self._deriver.derive(msg)]
            derived += self._plotter.derive(msg)
        except (ValueError, TypeError, KeyError, IndexError):  # a view must never stop the recording
            self.derived_errors += 1
            return
        for topic, schema_name, data in derived:
            channel_id = self._derived_channels.get(topic)
            if channel_id is None:
                schema_id = self._derived_schemas.get(schema_name)
                if schema_id is None:
                    schema_data = SCENE_UPDATE_SCHEMA_BYTES if schema_name == DERIVED_SCHEMA else PLOT_SCHEMAS[schema_name]
                    schema_id = self._writer.register_schema(schema_name, SCHEMA_ENCODING, schema_data)
                    self._derived_schemas[schema_name] = schema_id
                channel_id = self._writer.register_channel(topic, DERIVED_ENCODING, schema_id,
                                                           {"derived_from": run_wildcard(self.run)})
                self._derived_channels[topic] = channel_id
            with self._lock:
                seq = self._derived_counts[topic] = self._derived_counts.get(topic, 0) + 1
            self._writer.add_message(channel_id, log_time, data, msg.stamp_ns, sequence=seq & 0xFFFFFFFF)

    def _loop(self) -> None:
        last_flush = time.monotonic()
        dirty = False
        try:
            while True:
                timeout = max(0.0, last_flush + self.flush_s - time.monotonic()) if dirty else None
                item: tuple[str, bytes, int | None, int] | tuple[()] | None
                try:
                    item = self._queue.get(timeout=timeout)
                except queue.Empty:
                    item = ()
                if item is None:
                    return
                if item:
                    self._write_now(*item)
                    dirty = True
                    if item[0].endswith("/coord/checkpoint"):  # what a resuming coordinator reads: on the disk now
                        self._writer.flush()
                        os.fsync(self._file.fileno())
                        last_flush, dirty = time.monotonic(), False
                        with self._durable:
                            self.checkpoints += 1
                            self._durable.notify_all()
                if dirty and time.monotonic() - last_flush >= self.flush_s:
                    self._writer.flush()  # closes the chunk in progress and flushes the file
                    last_flush, dirty = time.monotonic(), False
        except BaseException as e:  # noqa: BLE001 - reported by on_error and close()
            self._error = e
        with self._durable:  # no checkpoint will reach the disk: nobody waits for one
            self._durable.notify_all()
        if self.on_error is not None:
            try:
                self.on_error(self._error)
            except Exception:  # noqa: BLE001 - the callback's failure must not hide the write error
                pass
        while (item := self._queue.get()) is not None:  # the rest is not written, only counted
            with self._lock:
                self.dropped += 1

    def wait_checkpoints(self, count: int, timeout_s: float) -> bool:
        """Until ``count`` checkpoints are on the disk (True), or ``timeout_s`` seconds have passed (False)."""
        with self._durable:
            return self._durable.wait_for(lambda: self.checkpoints >= count or self._error is not None, timeout_s) \
                and self.checkpoints >= count

    def close(self) -> None:
        """Write every queued message, the ``recorder`` metadata and the summary; close the file."""
        if self._closed:
            return
        self._closed = True
        self._queue.put(None)
        self._thread.join()
        try:
            with self._lock:
                stats = {"messages": sum(self._counts.values()), "undecodable": sum(self._bad.values()),
                         "derived_messages": sum(self._derived_counts.values()), "derived_errors": self.derived_errors,
                         "stopped_ns": time.time_ns(), "clean_stop": self._error is None, "dropped": self.dropped}
            self._writer.add_metadata("recorder", _metadata_map(stats))
            self._writer.finish()
        except Exception as e:  # noqa: BLE001 - after a write error the summary may not fit either
            if self._error is None:
                self._error = e
        finally:
            try:
                self._file.close()
            except OSError:
                pass
        if self._error is not None:
            raise RecordingFailed(self.path, self._error, self.count, self.dropped) from self._error

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RecordingFailed(RecordingError):
    """Writing a recording failed: ``path``, the ``error``, messages ``written`` before it and ``dropped`` after it."""

    def __init__(self, path: Path, error: BaseException, written: int, dropped: int) -> None:
        detail = error.strerror if isinstance(error, OSError) and error.strerror else str(error) or type(error).__name__
        super().__init__(f"recording to {path} failed after {written} messages: {detail}; {dropped} later messages not recorded")
        self.path, self.error, self.written, self.dropped = path, error, written, dropped


def record_run(settings: ZenohSettings, run: str, path: str | os.PathLike[str], metadata: dict[str, Any] | None,
               stop_event: threading.Event, on_ready: Callable[[McapRecorder], object] | None = None,
               on_error: Callable[[BaseException], object] | None = None, drain_s: float = 0.0) -> dict[str, Any]:
    """Record ``swarm/<run>/**`` through a Zenoh session opened with ``settings`` until ``stop_event`` is set, then
    until ``drain_s`` seconds pass without a new message (``drain``: what was in flight at the stop is kept).

    ``on_ready(recorder)`` is called once the subscription is declared, ``on_error(error)`` once if
    writing fails (the recording then goes on counting, ``close`` raises ``RecordingFailed``). Returns ``{"path",
    "messages", "channels", "raw_messages", "raw_channels", "derived_messages", "derived_channels",
    "undecodable"}`` (``messages`` and ``channels`` count raw and derived ones, as ``swarm info`` does).
    """
    from runtime.wire.transport import open_session, subscribe  # noqa: PLC0415 - zenoh only when recording live

    with open_session(settings) as session:  # fails (ConnectionError) before any file is created
        recorder = McapRecorder(path, run, metadata, on_error=on_error)
        try:
            sub = subscribe(session, run_wildcard(run), lambda key, payload: recorder.write(key, payload))
            if on_ready is not None:
                on_ready(recorder)
            while not stop_event.wait(0.1):
                pass
            drain(recorder, drain_s)
            sub.undeclare()
        finally:
            recorder.close()
    raw, derived = recorder.counts(), recorder.derived_counts()
    return {"path": str(recorder.path), "messages": sum(raw.values()) + sum(derived.values()), "channels": len(raw) + len(derived),
            "raw_messages": sum(raw.values()), "raw_channels": len(raw), "derived_messages": sum(derived.values()),
            "derived_channels": len(derived), "undecodable": sum(recorder.bad_counts().values())}


def drain(recorder: McapRecorder, quiet_s: float) -> None:
    """Wait until ``quiet_s`` seconds pass without a message written by ``recorder``, at most ``DRAIN_LIMIT``
    times ``quiet_s`` in all: messages published before a stop but still in flight then are recorded."""
    if quiet_s <= 0:
        return
    deadline = time.monotonic() + DRAIN_LIMIT * quiet_s
    seen = recorder.count
    while time.monotonic() < deadline:
        time.sleep(quiet_s)
        if recorder.count == seen:
            return
        seen = recorder.count


def run_metadata(hub: str, command: str, seed: int | None = None, trajectory: Path | None = None,
                 params: Iterable[str] = ()) -> dict[str, Any]:
    """The run metadata ``swarm record`` stores: the hub, its command line, the seed, the trajectory file's JSON
    and ``KEY=VALUE`` parameters (VALUE parsed as JSON when it is JSON)."""
    meta: dict[str, Any] = {"hub": hub, "command": command}
    if seed is not None:
        meta["seed"] = seed
    if trajectory is not None:
        try:
            meta["trajectory"] = json.loads(trajectory.read_text())
        except (OSError, ValueError) as exc:
            raise SwarmInputError(f"trajectory {trajectory}: cannot read it as JSON: {exc}") from None
    values = {}
    for item in params:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise OptionError("param", f"{item!r}: use KEY=VALUE")
        try:
            values[key] = json.loads(value)
        except ValueError:
            values[key] = value
    if values:
        meta["parameters"] = values
    return meta


def counts_text(counts: dict[str, Any]) -> str:
    """``N messages on C channels (R raw on RC, D derived on DC)`` from ``record_run``'s or ``recording_info``'s counts:
    the recorder and ``swarm info`` print the same numbers for the same file."""
    channels = counts["channels"] if isinstance(counts["channels"], int) else len(counts["channels"])  # recording_info lists them
    return (f"{counts['messages']} messages on {channels} channels ({counts['raw_messages']} raw on "
            f"{counts['raw_channels']}, {counts['derived_messages']} derived on {counts['derived_channels']})")


def _utc(ns: int | None) -> str:
    if ns is None:
        return "-"
    return datetime.fromtimestamp(ns / 1e9, UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + " UTC"


def info_text(info: dict[str, Any]) -> str:
    """``recording_info`` as ``swarm info`` prints it: file state, counts, times, a table of the channels, the metadata."""
    out: list[str] = []
    state = "finished, indexed" if info["indexed"] else "finished, no index" if info["complete"] else "UNFINISHED"
    out.append(f"file:      {info['path']} ({info['bytes']} bytes, {state})")
    if not info["complete"]:
        lost = info["bytes"] - info["readable_bytes"]
        out.append(f"           read up to byte {info['readable_bytes']} ({lost} bytes of an incomplete record dropped): {info['problem']}")
        out.append(f"           'swarm recover {info['path']}' writes a finished copy")
    out.append(f"messages:  {counts_text(info)}, {info['undecodable']} undecodable")
    out.append(f"start:     {_utc(info['first_ns'])}")
    out.append(f"end:       {_utc(info['last_ns'])}")
    out.append(f"duration:  {info['duration_s']:.3f} s")
    if info["channels"]:
        width = max(len(c["topic"]) for c in info["channels"])
        tw = max(18, *(len(c["type"] or "") for c in info["channels"]))
        out.append(f"{'topic':<{width}}  {'type':<{tw}} {'count':>7} {'bad':>5}  {'first (s)':>9} {'last (s)':>9}")
        t0 = info["first_ns"] or 0
        for c in info["channels"]:
            first = "-" if c["first_ns"] is None else f"{(c['first_ns'] - t0) / 1e9:.3f}"
            last = "-" if c["last_ns"] is None else f"{(c['last_ns'] - t0) / 1e9:.3f}"
            bad = "-" if c["type"] is None else str(c["undecodable"])
            reasons = f"  ({', '.join(f'{r}: {n}' for r, n in sorted(c['reasons'].items()))})" if c["reasons"] else ""
            out.append(f"{c['topic']:<{width}}  {c['type'] or '(no schema)':<{tw}} {c['messages']:>7} {bad:>5}  {first:>9} {last:>9}{reasons}")
    for name, values in info["metadata"].items():
        out.append(f"metadata {name}:")
        for key, value in values.items():
            text = value if isinstance(value, str) else json.dumps(value, sort_keys=True)
            out.append(f"  {key}: {text if len(text) <= 200 else text[:197] + '...'}")
    return "\n".join(out)


# ---------------------------------------------------------------- reading


class _Bounded:
    """A read-only view of the first ``end`` bytes of a file: no read can ask for more than is there.

    Deliberately not an ``io.RawIOBase``: mcap's StreamReader would wrap that in a
    BufferedReader, whose garbage collection closes the underlying file.
    """

    def __init__(self, f: io.BufferedReader, end: int) -> None:
        self._f, self._end = f, end
        self._f.seek(0)

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self._f.tell()

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        target = {io.SEEK_SET: offset, io.SEEK_CUR: self._f.tell() + offset, io.SEEK_END: self._end + offset}[whence]
        return self._f.seek(min(max(target, 0), self._end))

    def read(self, n: int = -1) -> bytes:
        left = self._end - self._f.tell()
        n = left if n is None or n < 0 else min(n, left)
        return self._f.read(max(n, 0))


@dataclass
class _Scan:
    """The record framing of a file: where its readable data ends and whether it is finished."""

    size: int
    end: int  # offset just after the last complete record (or the end magic of a finished file)
    complete: bool  # footer and closing magic present
    indexed: bool  # a summary section (the seeking reader's index) is present
    problem: str = ""  # why reading stops before the end of the file, if it does


def _bad(path: Path, problem: str) -> SwarmInputError:
    return SwarmInputError(f"{path}: {problem}")


def is_finished(path: str | os.PathLike[str]) -> bool:
    """Whether the MCAP file at ``path`` was finished (footer and closing magic): False for a recording cut short."""
    try:
        with open(path, "rb") as f:
            return _has_footer(f, os.fstat(f.fileno()).st_size)
    except OSError:
        return False


def _has_footer(f: io.BufferedReader, size: int) -> bool:
    """Whether the file ends like a finished MCAP: a 20-byte footer record, then the magic."""
    if size < 8 + 9 + 20 + 8:
        return False
    f.seek(size - 8 - 29)
    tail = f.read(29 + 8)
    return tail[0] == Opcode.FOOTER and tail[1:9] == struct.pack("<Q", 20) and tail[29:] == MAGIC


def _scan(path: Path, f: io.BufferedReader) -> _Scan:
    size = os.fstat(f.fileno()).st_size
    f.seek(0)
    magic = f.read(8)
    if len(magic) < 8:
        raise _bad(path, f"not an MCAP file: {size} bytes, shorter than the 8-byte magic")
    if magic != MAGIC:
        raise _bad(path, f"not an MCAP file: starts with {magic!r}, expected the MCAP magic {MAGIC!r}")
    pos, first = 8, True
    while True:
        if pos == size:
            return _Scan(size, pos, False, False, "" if not first else "no header record")
        head = f.read(9)
        if len(head) < 9:
            if first:
                raise _bad(path, f"truncated header: the file ends {len(head)} bytes into the header record")
            return _Scan(size, pos, False, False, f"{len(head)} bytes of an incomplete record at offset {pos}")
        opcode, length = head[0], struct.unpack("<Q", head[1:])[0]
        if first and opcode != Opcode.HEADER:
            raise _bad(path, f"corrupt: the first record (offset 8) has opcode 0x{opcode:02x}, expected a header (0x01)")
        if opcode not in _KNOWN_OPCODES and opcode < 0x80:
            raise _bad(path, f"corrupt at offset {pos}: invalid record opcode 0x{opcode:02x}")
        if length > MAX_RECORD_BYTES:
            raise _bad(path, f"corrupt at offset {pos}: {Opcode(opcode).name if opcode in _KNOWN_OPCODES else hex(opcode)} "
                             f"record claims {length} bytes")
        if pos + 9 + length > size:
            if _has_footer(f, size):
                raise _bad(path, f"corrupt at offset {pos}: a record claims {9 + length} bytes, past the end of the "
                                 "file, yet the file ends with a footer (it is damaged, not cut off)")
            if first:
                raise _bad(path, f"truncated header: the header record needs {length} bytes, {size - pos - 9} remain")
            return _Scan(size, pos, False, False, f"incomplete record at offset {pos} ({size - pos} of {9 + length} bytes)")
        first = False
        if opcode == Opcode.FOOTER:
            f.seek(pos + 9)
            body = f.read(length)
            summary_start = struct.unpack("<Q", body[:8])[0] if len(body) >= 8 else 0
            f.seek(pos + 9 + length)
            tail = f.read(8)
            if tail != MAGIC:
                raise _bad(path, f"corrupt: the footer at offset {pos} is not followed by the closing magic")
            end = pos + 9 + length + 8
            if end != size:
                raise _bad(path, f"corrupt: {size - end} bytes after the closing magic at offset {end}")
            return _Scan(size, end, True, 0 < summary_start < pos)
        pos += 9 + length
        f.seek(pos)


@dataclass
class RecordingStatus:
    """What reading a recording found (filled in while ``_records`` runs)."""

    complete: bool = False
    indexed: bool = False
    reader: str = ""
    size: int = 0
    readable_bytes: int = 0
    problem: str = ""
    profile: str = ""
    library: str = ""
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)


def _wrap(path: Path, exc: BaseException, where: str) -> SwarmInputError:
    text = str(exc) or type(exc).__name__
    return _bad(path, f"corrupt {where}: {type(exc).__name__}: {text}")


def _records(path: str | os.PathLike[str], status: RecordingStatus,
             seeking: bool = True) -> Iterator[Schema | Channel | Message | Metadata | Attachment]:
    """Schemas, channels, metadata, attachments and messages of a recording, in file order.

    A finished, indexed file is read with the seeking reader (unless ``seeking`` is False);
    anything else with the stream reader up to the last complete record.
    """
    path = Path(path)
    try:
        f = open(path, "rb")
    except FileNotFoundError:
        raise _bad(path, "no such file") from None
    except IsADirectoryError:
        raise _bad(path, "is a directory, not an MCAP file") from None
    with f:
        scan = _scan(path, f)
        status.complete, status.indexed, status.size = scan.complete, scan.indexed, scan.size
        status.readable_bytes, status.problem = scan.end, scan.problem
        view = cast(IO[bytes], _Bounded(f, scan.end))  # duck-typed: only what mcap's readers call
        if scan.indexed and seeking:
            status.reader = "seeking"
            try:
                reader = SeekingReader(view, validate_crcs=True)
                header = reader.get_header()
                summary = reader.get_summary()
            except _READ_ERRORS as e:
                raise _wrap(path, e, "summary") from None
            assert summary is not None  # the scan found the summary (indexed)
            status.profile, status.library = header.profile, header.library
            status.schemas.update(summary.schemas)
            status.channels.update(summary.channels)
            yield from summary.schemas.values()
            yield from summary.channels.values()
            try:
                yield from reader.iter_metadata()
                yield from reader.iter_attachments()
                for _schema, _channel, message in reader.iter_messages(log_time_order=False):
                    yield message
            except _READ_ERRORS as e:
                raise _wrap(path, e, "data") from None
            return
        status.reader = "stream"
        records = StreamReader(view, validate_crcs=True, record_size_limit=MAX_RECORD_BYTES).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except EndOfFile:
                if view.tell() >= scan.end and not scan.complete:
                    return  # the last complete record was read: a truncated (killed) recording ends here
                raise _bad(path, f"corrupt: a record ends past the readable data (offset {view.tell()})") from None
            except _READ_ERRORS as e:
                raise _wrap(path, e, f"record before offset {view.tell()}") from None
            if isinstance(record, Schema):
                status.schemas[record.id] = record
            elif isinstance(record, Channel):
                status.channels[record.id] = record
            elif isinstance(record, Message):
                if record.channel_id not in status.channels:
                    raise _bad(path, f"corrupt: a message on channel {record.channel_id}, which was never defined")
            elif not isinstance(record, (Metadata, Attachment)):
                if isinstance(record, Header):
                    status.profile, status.library = record.profile, record.library
                continue
            yield record


def is_derived(topic: str) -> bool:
    """Whether ``topic`` is a derived channel (``/foxglove/...`` scenes, ``/robot/...`` and ``/swarm/...``
    plottable JSON), not a Zenoh key of the run (those never start with ``/``)."""
    return topic.startswith(DERIVED_PREFIX) or is_plot_topic(topic)


def read_messages(path: str | os.PathLike[str], derived: bool = False) -> Iterator[tuple[str, bytes, int, int]]:
    """``(topic, payload, log_time_ns, publish_time_ns)`` of every message of the run, in file order.

    The derived Foxglove channels (``is_derived``) are skipped unless ``derived`` is True,
    so what is yielded is exactly what was received on ``swarm/<run>/**``.
    Works on unfinished (killed) recordings: they end at the last complete chunk.
    """
    status = RecordingStatus()
    for record in _records(path, status):
        if isinstance(record, Message):
            topic = status.channels[record.channel_id].topic
            if derived or not is_derived(topic):
                yield topic, record.data, record.log_time, record.publish_time


def recording_status(path: str | os.PathLike[str]) -> RecordingStatus:
    """What reading ``path`` through finds (finished or not, readable bytes, the problem), without decoding a message."""
    status = RecordingStatus()
    for _record in _records(path, status):
        pass
    return status


def recording_info(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Channels (type, count, first/last log time, undecodable count and reasons), duration, metadata, completeness."""
    status = RecordingStatus()
    channels: dict[int, dict[str, Any]] = {}
    meta: dict[str, Any] = {}
    attachments = 0
    for record in _records(path, status):
        if isinstance(record, Channel):
            schema = status.schemas.get(record.schema_id)
            channels.setdefault(record.id, {"topic": record.topic, "type": schema.name if schema else None,
                                            "message_encoding": record.message_encoding, "messages": 0,
                                            "first_ns": None, "last_ns": None, "undecodable": 0, "reasons": {},
                                            "derived": is_derived(record.topic)})
        elif isinstance(record, Metadata):
            meta[record.name] = _metadata_values(record.metadata)
        elif isinstance(record, Attachment):
            attachments += 1
        elif isinstance(record, Message):
            ch = channels[record.channel_id]
            ch["messages"] += 1
            t = record.log_time
            ch["first_ns"] = t if ch["first_ns"] is None else min(ch["first_ns"], t)
            ch["last_ns"] = t if ch["last_ns"] is None else max(ch["last_ns"], t)
            if ch["type"] is not None and ch["message_encoding"] == MESSAGE_ENCODING:
                try:
                    decode(record.data, key=ch["topic"])
                except MessageError as e:
                    ch["undecodable"] += 1
                    ch["reasons"][e.reason] = ch["reasons"].get(e.reason, 0) + 1
    firsts = [c["first_ns"] for c in channels.values() if c["first_ns"] is not None]
    lasts = [c["last_ns"] for c in channels.values() if c["last_ns"] is not None]
    first, last = (min(firsts), max(lasts)) if firsts else (None, None)
    return {
        "path": str(path),
        "complete": status.complete,
        "indexed": status.indexed,
        "reader": status.reader,
        "bytes": status.size,
        "readable_bytes": status.readable_bytes,
        "problem": status.problem,
        "library": status.library,
        "messages": sum(c["messages"] for c in channels.values()),
        "raw_messages": sum(c["messages"] for c in channels.values() if not c["derived"]),
        "raw_channels": sum(1 for c in channels.values() if not c["derived"]),
        "derived_messages": sum(c["messages"] for c in channels.values() if c["derived"]),
        "derived_channels": sum(1 for c in channels.values() if c["derived"]),
        "undecodable": sum(c["undecodable"] for c in channels.values()),
        "first_ns": first,
        "last_ns": last,
        "duration_s": (last - first) / 1e9 if first is not None and last is not None else 0.0,
        "schemas": sorted({s.name for s in status.schemas.values()}),
        "channels": sorted(channels.values(), key=lambda c: c["topic"]),
        "metadata": meta,
        "attachments": attachments,
    }


def recover(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> dict[str, Any]:
    """Rewrite ``src`` (finished or not) as a finished, indexed MCAP at ``dst``.

    Same schemas, channels, metadata, attachments and messages (bytes, times and sequence
    unchanged, file order); ids may be renumbered. Written to a temporary file first.
    ``SwarmInputError`` (nothing written) when ``src`` holds no complete message.
    """
    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise SwarmInputError(f"{dst}: recover needs an output file different from its input")
    status = RecordingStatus()
    tmp = dst.with_name(dst.name + ".part")
    dst.parent.mkdir(parents=True, exist_ok=True)
    schema_ids: dict[int, int] = {0: 0}
    channel_ids: dict[int, int] = {}
    messages = 0
    meta_count = 0
    try:
        with open(tmp, "wb") as out:
            writer: Writer | None = None
            for record in _records(src, status, seeking=False):
                if writer is None:
                    writer = Writer(out, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
                    writer.start(profile=status.profile, library=status.library or "inchworm-swarm recover")
                if isinstance(record, Schema):
                    if record.id not in schema_ids:
                        schema_ids[record.id] = writer.register_schema(record.name, record.encoding, record.data)
                elif isinstance(record, Channel):
                    if record.id not in channel_ids:
                        if record.schema_id not in schema_ids:
                            raise _bad(src, f"corrupt: channel {record.topic!r} uses schema {record.schema_id}, which was never defined")
                        channel_ids[record.id] = writer.register_channel(
                            record.topic, record.message_encoding, schema_ids[record.schema_id], dict(record.metadata))
                elif isinstance(record, Metadata):
                    writer.add_metadata(record.name, dict(record.metadata))
                    meta_count += 1
                elif isinstance(record, Attachment):
                    writer.add_attachment(record.create_time, record.log_time, record.name, record.media_type, record.data)
                elif isinstance(record, Message):
                    writer.add_message(channel_ids[record.channel_id], record.log_time, record.data, record.publish_time, record.sequence)
                    messages += 1
            if not messages:  # a header, perhaps schemas and channels: a "recovered" file would hold no run
                raise SwarmInputError(
                    f"{src}: nothing to recover: no complete message in its {status.readable_bytes} readable bytes "
                    f"(of {status.size}); no output written")
            assert writer is not None  # opened at the first record
            writer.finish()
        os.replace(tmp, dst)
    finally:
        if tmp.exists():
            tmp.unlink()
    return {"source": str(src), "path": str(dst), "source_complete": status.complete, "messages": messages,
            "channels": len(channel_ids), "schemas": len(schema_ids) - 1, "metadata": meta_count,
            "dropped_bytes": status.size - status.readable_bytes if not status.complete else 0}
