"""The frame byte stream over an ANT USB stick (optional extra: ``pip install -e '.[ant]'``, openant).

A port with ``"transport": "ant"`` and ``"device": "ant:<device_number>[:<rf_channel>]"`` in
the gateway config is served by this ``ByteLink``: the gateway's stick opens one
bidirectional master channel (ANT public network, device type ``DEVICE_TYPE``,
transmission type ``TRANS_TYPE``, message period ``PERIOD`` = 32768/8192 s = 4 Hz, RF
channel 2400 + rf_channel MHz, default 66). Outgoing bytes (whole frames of
docs/gateway-protocol.md) go out as burst transfers, padded with zero bytes to a multiple
of 8 (the receiver's resynchronisation skips bytes before a START); every broadcast,
acknowledged or burst payload received is appended to the incoming byte stream. The
robots' firmware opens the matching slave channel.

Not tried on hardware (no ANT stick here): this follows the openant 1.3 ``easy`` API
(``Node``, ``Channel``); only its import and configuration errors are tested.
"""

from __future__ import annotations

import queue
import re
import threading
from collections.abc import Iterable

from runtime.errors import SwarmConnectionError, SwarmInputError

PUBLIC_NETWORK_KEY = [0xE8, 0xE4, 0x21, 0x3B, 0x55, 0x7A, 0x67, 0xC1]
DEVICE_TYPE = 0x42
TRANS_TYPE = 0x01
PERIOD = 8192
DEFAULT_RF = 66
_DEVICE = re.compile(r"ant:(?P<num>[0-9]{1,5})(:(?P<rf>[0-9]{1,3}))?")
INSTALL_HINT = "pip install -e '.[ant]'"


def parse_ant_device(device: str) -> tuple[int, int]:
    """(device number 1..65535, RF channel 0..124) of ``ant:<device_number>[:<rf_channel>]``."""
    m = _DEVICE.fullmatch(device)
    if m is None:
        raise SwarmInputError(f"ANT device {device!r} is invalid: use ant:<device_number>[:<rf_channel>], e.g. ant:17:66")
    number, rf = int(m["num"]), int(m["rf"] or DEFAULT_RF)
    if not 1 <= number <= 0xFFFF or not 0 <= rf <= 124:
        raise SwarmInputError(f"ANT device {device!r}: device number must be in [1, 65535] and RF channel in [0, 124]")
    return number, rf


class AntLink:
    """``ByteLink`` over the first ANT USB stick (see module doc)."""

    def __init__(self, device: str) -> None:
        number, rf = parse_ant_device(device)
        try:
            from openant.easy.channel import Channel  # noqa: PLC0415 - optional extra
            from openant.easy.node import Node  # noqa: PLC0415
        except ImportError as exc:
            raise SwarmInputError(f"the ANT transport needs openant, which is not installed ({exc}): {INSTALL_HINT}") from None
        self._rx: queue.Queue[bytes] = queue.Queue()
        try:
            self._node = Node()
            self._node.set_network_key(0, PUBLIC_NETWORK_KEY)
            channel = self._node.new_channel(Channel.Type.BIDIRECTIONAL_TRANSMIT)
            channel.on_broadcast_data = channel.on_acknowledge_data = channel.on_burst_data = self._receive
            channel.set_id(number, DEVICE_TYPE, TRANS_TYPE)
            channel.set_rf_freq(rf)
            channel.set_period(PERIOD)
            channel.open()
        except Exception as exc:  # noqa: BLE001 - openant raises its own and USB errors
            raise SwarmConnectionError(f"cannot open the ANT channel {device}: {exc}") from None
        self._channel = channel
        self._thread = threading.Thread(target=self._node.start, name=f"ant-{number}", daemon=True)
        self._thread.start()

    def _receive(self, data: Iterable[int]) -> None:  # openant hands the payload as a sequence of bytes
        self._rx.put(bytes(data))

    def read(self, timeout_s: float) -> bytes:
        try:
            data = self._rx.get(timeout=timeout_s)
        except queue.Empty:
            return b""
        while not self._rx.empty():
            data += self._rx.get_nowait()
        return data

    def write(self, data: bytes) -> None:
        padded = data + bytes(-len(data) % 8)
        self._channel.send_burst_transfer(list(padded))

    def close(self) -> None:
        self._node.stop()
