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




# files a zenoh config may name; zenoh itself reports a missing connect-side one only as a failed connect
_FILE_KEYS = ("transport/link/tls/root_ca_certificate", "transport/link/tls/listen_private_key",
              "transport/link/tls/listen_certificate", "transport/link/tls/connect_private_key",
              "transport/link/tls/connect_certificate", "transport/auth/usrpwd/dictionary_file")


def _get(conf, key, default=None):
    try:
        return json.loads(conf.get_json(key))
    except Exception:                 # zenoh raises for a key the config does not have
        return default


def check_zenoh_config(conf) -> None:
    """Refuse a config zenoh would refuse, without touching the real network: the files it names must
    be readable, and a copy of it must open with its listeners on ephemeral loopback ports and no
    connections (that loads TLS listener files and the access-control policy). BadConfig otherwise."""
    import os

    import zenoh

    for key in _FILE_KEYS:
        path = _get(conf, key)
        if path and not os.access(path, os.R_OK):
            raise BadConfig(f"zenoh config {key} = {path!r}: no such file or not readable")
    dry = zenoh.Config.from_json5(str(conf))
    mode = _get(conf, "mode") or "peer"
    listen = _get(conf, "listen/endpoints") or []
    if isinstance(listen, dict):      # the per-mode form {router: [...], peer: [...]}
        listen = listen.get(mode, [])
    loopback = [f"{e.partition('/')[0]}/127.0.0.1:0" for e in listen
                if e.partition("/")[0] in ("tcp", "tls", "udp", "quic", "ws")]
    dry.insert_json5("listen/endpoints", json.dumps(loopback))
    dry.insert_json5("connect/endpoints", "[]")
    dry.insert_json5("scouting/multicast/enabled", "false")
    dry.insert_json5("scouting/gossip/enabled", "false")
    if mode == "client":              # a client with nothing to connect to never opens
        dry.insert_json5("mode", '"peer"')
    try:
        zenoh.open(dry).close()
    except Exception as exc:
        raise BadConfig(f"zenoh refuses the configuration: {zenoh_message(exc)}") from None


def command_access(conf, name: str) -> str:
    """"authenticated" when access control lets only authenticated subjects (certificate common
    names or user names) query crawler/<name>/cmd/**, else "open"."""
    import zenoh

    acl = _get(conf, "access_control") or {}
    if not acl.get("enabled"):
        return "open"
    cmd = zenoh.KeyExpr(f"crawler/{name}/cmd/reset")
    rules = {r.get("id"): r for r in acl.get("rules") or []}
    subjects = {s.get("id"): s for s in acl.get("subjects") or []}

    def grants(rule) -> bool:
        return (rule.get("permission") == "allow" and "query" in (rule.get("messages") or [])
                and "ingress" in (rule.get("flows") or ["ingress", "egress"])
                and any(zenoh.KeyExpr(k).intersects(cmd) for k in rule.get("key_exprs") or []))

    def authenticated(subject) -> bool:
        return bool(subject.get("cert_common_names") or subject.get("usernames"))

    for policy in acl.get("policies") or []:
        if any(grants(rules.get(r, {})) for r in policy.get("rules") or []):
            if not all(authenticated(subjects.get(s, {})) for s in policy.get("subjects") or []):
                return "open"
    return "open" if acl.get("default_permission") == "allow" else "authenticated"
