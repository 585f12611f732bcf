"""The settings of a Zenoh router of a multi-host swarm (``swarm router``): a config file, its TLS files, the endpoints."""

from __future__ import annotations

import json
import os

import zenoh

from runtime.errors import OptionError, SwarmInputError
from runtime.wire.tls_files import check_tls_files
from runtime.wire.transport import ZenohSettings

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"
def _file_endpoints(config: zenoh.Config) -> list[str]:
    """The listen endpoints a config file gives a router (the field may be per mode)."""
    value = json.loads(config.get_json("listen/endpoints"))
    if isinstance(value, dict):
        value = value.get("router", [])
    return list(value or [])


def router_settings(listen: list[str], config_file: str | None) -> ZenohSettings:
    """The router's ``ZenohSettings``: checks the file, its TLS paths and the endpoints (no port 0)."""
    endpoints = tuple(listen)
    if config_file is not None:
        if not os.path.isfile(config_file) or not os.access(config_file, os.R_OK):
            raise OptionError("config", f"{config_file!r} is not a readable file")
        config = ZenohSettings("router", config_file=config_file).to_config()  # SwarmInputError if invalid
        check_tls_files(config, str(config_file))
        if not endpoints:
            endpoints = tuple(_file_endpoints(config))
    settings = ZenohSettings("router", listen=endpoints or (DEFAULT_LISTEN,), config_file=config_file)
    for endpoint in settings.listen:
        if endpoint.split("?")[0].split("#")[0].endswith(":0"):
            raise SwarmInputError(f"listen endpoint {endpoint!r}: give a fixed port (clients must know it)")
    return settings
