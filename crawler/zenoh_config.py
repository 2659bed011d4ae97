"""Zenoh configuration: flags and [zenoh] settings into a zenoh.Config, checked before any network.

A configuration error (a bad endpoint, a broken access-control policy, a missing certificate) is not a
network error: it is refused at start with one line and exit 2, never retried forever. Whether
commands are open to anyone or restricted by access control is read from the config, so the daemon
can say so at start and in its status.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from .errors import BadConfig

def zenoh_message(exc) -> str:
    """zenoh's error text without the Rust source locations it appends."""
    return re.sub(r" at /\S+?:\d+\.?", "", str(exc)).strip()


def _check_ports(kind: str, endpoints) -> None:
    """zenoh parses endpoints but accepts any port for `connect` (it just never connects): refuse it."""
    for e in endpoints:
        m = re.match(r"^(tcp|udp|tls|quic|ws)/.*:(\d+)(?:[?#].*)?$", str(e))
        if m and not 0 < int(m.group(2)) < 65536:
            raise BadConfig(f"[zenoh] {kind} endpoint {e!r}: port {m.group(2)} must be 1..65535")


def make_zenoh_config(mode: str | None = "peer", listen=(), connect=(), config_file: str | None = None,
                      multicast: bool = True):
    """One place that turns flags/TOML into a zenoh.Config, naming the culprit when it fails."""
    import zenoh

    _check_ports("listen", listen)
    _check_ports("connect", connect)

    if config_file:
        path = Path(config_file)
        if not path.is_file():
            raise BadConfig(f"[zenoh] config = {config_file!r}: no such file (a zenoh JSON5 config)")
        try:
            conf = zenoh.Config.from_file(str(path))
        except Exception as exc:   # zenoh raises its own ZError
            raise BadConfig(f"[zenoh] config = {config_file!r} is not a valid zenoh config: "
                            f"{zenoh_message(exc)}") from None
    else:
        conf = zenoh.Config()
    if mode is None and not config_file:
        mode = "peer"
    try:
        if mode is not None:     # else the config file's own mode stands
            conf.insert_json5("mode", json.dumps(mode))
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        if not multicast:
            conf.insert_json5("scouting/multicast/enabled", "false")
    except Exception as exc:
        raise BadConfig(f"zenoh endpoints listen={list(listen)} connect={list(connect)} rejected: "
                        f"{zenoh_message(exc)}; an endpoint looks like tcp/192.168.1.10:7447") from None
    return conf


