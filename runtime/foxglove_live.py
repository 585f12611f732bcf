"""Live view of a run in the Foxglove app over the Foxglove WebSocket protocol (optional extra ``foxglove``).

    view = LiveView(port=8765, host="127.0.0.1", trajectory=traj_json)   # starts the server
    subscribe(session, run_wildcard(run), view.handle)                    # every key, raw payload
    ...
    view.close()

``handle(key, payload)`` decodes a raw message, derives the same ``foxglove.SceneUpdate``
scenes the recorder writes (``runtime.foxglove_scene``: ``/foxglove/estimated``,
``/foxglove/true``, ``/foxglove/desired``) and logs them as JSON on channels of a
``foxglove.start_server`` WebSocket server; in the Foxglove app: Open connection ->
Foxglove WebSocket -> ``ws://<host>:<port>``, then a 3D panel with display frame ``world``.
Messages that do not decode, and keys that feed no scene, are ignored (counted in
``dropped``); ``handle`` never raises for bad input and is thread-safe.

foxglove-sdk is imported only here, when a ``LiveView`` is built; without it the
constructor raises ``SwarmInputError`` naming the extra to install.
"""

from __future__ import annotations

import threading
from typing import Any

from runtime.errors import SwarmInputError
from runtime.foxglove_scene import (
    MESSAGE_ENCODING,
    SCENE_UPDATE_SCHEMA_BYTES,
    SCHEMA_ENCODING,
    SCHEMA_NAME,
    TOPICS,
    SceneDeriver,
)
from runtime.keys import KeyspaceError
from runtime.messages import MessageError, decode, type_for_key

INSTALL_HINT = "pip install -e '.[foxglove]'"


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

    def __init__(self, port: int = 8765, host: str = "127.0.0.1", *, trajectory: Any = None, name: str = "inchworm-swarm") -> None:
        foxglove = _import_foxglove()
        self._deriver = SceneDeriver(trajectory)
        self._lock = threading.Lock()
        self.handled = 0
        self.dropped = 0
        self._closed = False
        self._context = foxglove.Context()
        schema = foxglove.Schema(name=SCHEMA_NAME, encoding=SCHEMA_ENCODING, data=SCENE_UPDATE_SCHEMA_BYTES)
        self._channels = {topic: foxglove.Channel(topic, schema=schema, message_encoding=MESSAGE_ENCODING, context=self._context)
                          for topic in TOPICS}
        try:
            self._server = foxglove.start_server(name=name, host=host, port=int(port), context=self._context)
        except Exception as exc:  # the SDK raises its own error types (port in use, bad host)
            raise SwarmInputError(f"cannot start the Foxglove WebSocket server on {host}:{port}: {exc}") from None
        self.host = host
        self.port = int(self._server.port)

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
        with self._lock:  # the deriver keeps the latest plan: one caller at a time
            scenes = self._deriver.derive(msg)
            self.handled += 1
            if not scenes:
                return
            for topic, scene in scenes:
                self._channels[topic].log(scene, log_time=msg.stamp_ns)

    def close(self) -> None:
        """Stop the server and close the channels (idempotent)."""
        if self._closed:
            return
        self._closed = True
        with self._lock:
            try:
                self._server.stop()
            finally:
                for channel in self._channels.values():
                    channel.close()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
