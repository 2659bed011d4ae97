"""crawler-monitor: watch, record and steer crawlers over Zenoh, from the operator's laptop.

Usage:
  crawler-monitor [watch] [--name NAME] [--record FILE.csv|FILE.jsonl] [--duration S] [--plain]
                                    live view of one crawler or the fleet (default: all, `*`)
  crawler-monitor plot FILE [-o OUT.png]
                                    distance and speed over time from a record, as a PNG
  crawler-monitor reset NAME        distance to 0, new run
  crawler-monitor led NAME LEVEL    LED level 0..1
  crawler-monitor status NAME       the daemon's status (NAME may be * for every crawler)

Zenoh flags (any command): --connect EP, --listen EP (repeatable), --zenoh-mode peer|client|router,
--zenoh-config FILE, --no-multicast; the same as crawlerd's. Default: peer with multicast scouting,
which finds crawlers on the same network by itself.

The live view redraws in place on a terminal; on a pipe it prints one line per update instead.
Exit status: 0 done (Ctrl-C and SIGTERM end a watch cleanly), 1 no crawler answered / the crawler
refused / zenoh failed, 2 bad arguments or an unreadable file. docs/operator.md has the details.
"""

from .cli import main

__all__ = ["main"]
