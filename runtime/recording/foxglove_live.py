"""Live view of a run in the Foxglove app over the Foxglove WebSocket protocol (optional extra ``foxglove``).

    view = LiveView(port=8765, host="127.0.0.1", trajectory=traj_json)   # starts the server
    subscribe(session, run_wildcard(run), view.handle)                    # every key, raw payload
    ...
    view.close()

``handle(key, payload)`` decodes a raw message, derives the same channels the recorder
writes (``runtime.recording.foxglove_scene``: ``/foxglove/estimated``, ``/foxglove/true``,
``/foxglove/desired`` scenes; ``runtime.recording.plot_channels``: ``/robot/<id>/estimate`` ... for
the Plot panel) and logs them as JSON on channels of a ``foxglove.start_server`` WebSocket
server; in the Foxglove app: Open connection -> Foxglove WebSocket -> ``ws://<host>:<port>``,
then a 3D panel with display frame ``world`` (or the layout ``docs/foxglove-layout.json``).
Messages that do not decode, and keys that feed no channel, are ignored (counted in
``dropped``); ``handle`` never raises for bad input and is thread-safe.

``linger(seconds)`` keeps the server up after the run (until Ctrl-C by default) and logs
the latest message of every channel again each ``REPEAT_S`` seconds, so an app that
connects late still shows the final state. A client that fails the WebSocket handshake
(a browser or a port scanner on the port) is logged once as a warning, then only counted
(``failed_handshakes``), not one ERROR line per attempt.

foxglove-sdk is imported only here, when a ``LiveView`` is built; without it the
constructor raises ``SwarmInputError`` naming the extra to install.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from runtime.errors import SwarmInputError
from runtime.recording.foxglove_scene import (
    MESSAGE_ENCODING,
    SCENE_UPDATE_SCHEMA_BYTES,
    SCHEMA_ENCODING,
    SCHEMA_NAME,
    TOPICS,
    SceneDeriver,
)
from runtime.recording.plot_channels import SCHEMA_BYTES as PLOT_SCHEMAS, PlotDeriver
from runtime.wire.keys import KeyspaceError
from runtime.wire.messages import MessageError, decode, type_for_key

INSTALL_HINT = "pip install -e '.[foxglove]'"
REPEAT_S = 1.0  # while lingering, the latest message of each channel is logged again this often
SERVER_LOGGER = "foxglove.websocket.server"  # where foxglove-sdk logs its server's events


class _HandshakeFilter(logging.Filter):
    """Lets the first failed WebSocket handshake through as one warning; counts and drops the later ones."""

    def __init__(self, url: str) -> None:
        super().__init__()
        self.url, self.count = url, 0

    def filter(self, record: logging.LogRecord) -> bool:
        if "handshake failed" not in record.getMessage():
            return True
        self.count += 1
        if self.count > 1:
            return False
        record.levelno, record.levelname = logging.WARNING, "WARNING"
        record.msg, record.args = (f"a client of {self.url} failed the WebSocket handshake ({record.getMessage()}); "
                                   "connect with the Foxglove app (Foxglove WebSocket); further failures are not logged"), ()
        return True


def require_foxglove() -> None:
    """``SwarmInputError`` naming the extra to install unless foxglove-sdk can be imported (check before starting a run)."""
    _import_foxglove()


def _import_foxglove() -> Any:
    try:
        import foxglove  # noqa: PLC0415 - optional dependency
    except ImportError as exc:
        raise SwarmInputError(f"the Foxglove live view needs foxglove-sdk, which is not installed ({exc}): "
                              f"{INSTALL_HINT}") from None
    return foxglove


class LiveView:
    """A Foxglove WebSocket server showing estimated (green), true (blue) and desired (red) positions.

    ``trajectory``: the run's trajectory JSON object (docs/trajectory.md), needed for the
    desired positions. ``port=0`` picks a free port (see ``port`` afterwards). Each view has
    its own foxglove ``Context``, so several views (or other foxglove users) do not mix.
    """

    def __init__(self, port: int = 8765, host: str = "127.0.0.1", *, trajectory: Any = None, name: str = "inchworm-swarm",
                 robot_radius: float = 0.0) -> None:
        foxglove = _import_foxglove()
        self._foxglove = foxglove
        self._deriver = SceneDeriver(trajectory, robot_radius)
        self._plotter = PlotDeriver(trajectory)
        self._lock = threading.Lock()
        self.handled = 0
        self.dropped = 0
        self._closed = False
        self._context = foxglove.Context()
        schema = foxglove.Schema(name=SCHEMA_NAME, encoding=SCHEMA_ENCODING, data=SCENE_UPDATE_SCHEMA_BYTES)
        self._channels = {topic: foxglove.Channel(topic, schema=schema, message_encoding=MESSAGE_ENCODING, context=self._context)
                          for topic in TOPICS}
        self._latest: dict[str, bytes] = {}  # topic -> the last message logged on it
        self._filter = _HandshakeFilter(f"ws://{host}:{port}")
        logging.getLogger(SERVER_LOGGER).addFilter(self._filter)
        try:
            self._server = foxglove.start_server(name=name, host=host, port=int(port), context=self._context)
        except Exception as exc:  # noqa: BLE001 - the SDK raises its own error types (port in use, bad host)
            logging.getLogger(SERVER_LOGGER).removeFilter(self._filter)
            raise SwarmInputError(f"cannot start the Foxglove WebSocket server on {host}:{port}: {exc}") from None
        self.host = host
        self.port = int(self._server.port)
        self._filter.url = self.url

    @property
    def failed_handshakes(self) -> int:
        """Clients that failed the WebSocket handshake so far (only the first is logged)."""
        return self._filter.count

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def handle(self, key: str, payload: bytes) -> None:
        """Decode one raw message of the run and send the scenes it gives (if any)."""
        if self._closed:
            return
        try:
            type_for_key(key)
            msg = decode(payload, key=key)
        except (MessageError, KeyspaceError):
            with self._lock:
                self.dropped += 1
            return
        with self._lock:  # the derivers keep the latest plan: one caller at a time
            try:
                out = [(topic, SCHEMA_NAME, scene) for topic, scene in self._deriver.derive(msg)] + self._plotter.derive(msg)
            except (ValueError, TypeError, KeyError, IndexError):  # a view never stops the run
                self.dropped += 1
                return
            self.handled += 1
            for topic, schema_name, data in out:
                self._channel(topic, schema_name).log(data, log_time=msg.stamp_ns)
                self._latest[topic] = data

    def _channel(self, topic: str, schema_name: str) -> Any:
        channel = self._channels.get(topic)
        if channel is None:  # a plot channel, created when its first message comes
            schema = self._foxglove.Schema(name=schema_name, encoding=SCHEMA_ENCODING, data=PLOT_SCHEMAS[schema_name])
            channel = self._channels[topic] = self._foxglove.Channel(topic, schema=schema, message_encoding=MESSAGE_ENCODING,
                                                                     context=self._context)
        return channel

    def linger(self, seconds: float | None = None) -> None:
        """Keep serving for ``seconds`` (None: until Ctrl-C, which returns normally), logging the latest
        message of every channel again every ``REPEAT_S`` s (stamped now) for apps that connect late."""
        deadline = None if seconds is None else time.monotonic() + seconds
        try:
            while deadline is None or time.monotonic() < deadline:
                with self._lock:
                    if self._closed:
                        return
                    now = time.time_ns()
                    for topic, data in self._latest.items():
                        self._channels[topic].log(data, log_time=now)
                time.sleep(REPEAT_S if deadline is None else max(0.0, min(REPEAT_S, deadline - time.monotonic())))
        except KeyboardInterrupt:
            return

    def close(self) -> None:
        """Stop the server and close the channels (idempotent)."""
        if self._closed:
            return
        self._closed = True
        with self._lock:
            try:
                self._server.stop()
            finally:
                logging.getLogger(SERVER_LOGGER).removeFilter(self._filter)
                for channel in self._channels.values():
                    channel.close()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
