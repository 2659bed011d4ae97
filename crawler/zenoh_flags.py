"""The Zenoh command-line flags, one definition for crawlerd and crawler-monitor.

They map onto [zenoh] settings keys, so a flag and the config file are one thing said twice.
"""

from __future__ import annotations

import argparse

ZENOH_MODES = ("peer", "client", "router")


def add_zenoh_flags(parser, suppress: bool = False):
    """Add --listen/--connect/--zenoh-mode/--zenoh-config/--no-multicast to a parser (or group).

    With `suppress`, defaults are argparse.SUPPRESS, so the flags may also follow a subcommand
    without overwriting values given before it.
    """
    d = (lambda v: argparse.SUPPRESS) if suppress else (lambda v: v)
    g = parser.add_argument_group("zenoh") if hasattr(parser, "add_argument_group") else parser
    g.add_argument("--listen", action="append", default=d([]), metavar="ENDPOINT",
                   help="e.g. tcp/0.0.0.0:7447 (repeatable; = [zenoh] listen)")
    g.add_argument("--connect", action="append", default=d([]), metavar="ENDPOINT",
                   help="e.g. tcp/192.168.1.10:7447 (repeatable; = [zenoh] connect)")
    g.add_argument("--zenoh-mode", choices=ZENOH_MODES, default=d(None),
                   help="= [zenoh] mode (peer, or the --zenoh-config file's)")
    g.add_argument("--zenoh-config", metavar="FILE", default=d(None),
                   help="a full zenoh JSON5 config (TLS, access control); = [zenoh] config")
    g.add_argument("--no-multicast", action="store_true", default=d(False),
                   help="no multicast scouting (fixed endpoints only); = [zenoh] multicast = false")
    return g


def zenoh_values(args) -> dict:
    """The [zenoh] settings the flags in `args` set: {"zenoh.listen": (...), ...}."""
    out = {}
    for flag, key in (("listen", "listen"), ("connect", "connect"), ("zenoh_mode", "mode"),
                      ("zenoh_config", "config")):
        value = getattr(args, flag, None)
        if value:
            out[f"zenoh.{key}"] = tuple(value) if isinstance(value, list) else value
    if getattr(args, "no_multicast", False):
        out["zenoh.multicast"] = False
    return out
