"""crawler-monitor: watch, record, steer and report crawlers over Zenoh, from the operator's laptop.

Usage:
  crawler-monitor [watch] [--name NAME] [--record FILE.csv|.jsonl|.mcap] [--duration S] [--plain]
                  [--foxglove [--foxglove-port 8765]]
                                    live view of one crawler or the fleet (default: all, `*`);
                                    keys: m marks an observation, q quits
  crawler-monitor plot FILE [-o OUT.png]     distance and speed over time from a record
  crawler-monitor report FILE [-o report.html|report.csv]
                                    the observation table with the distance and speed plots
  crawler-monitor reset NAME                 distance to 0, new run
  crawler-monitor led NAME LEVEL             LED level 0..1
  crawler-monitor zero NAME                  footage counter to 0 here (the start manhole)
  crawler-monitor preset NAME DISTANCE [--unit m|ft]   footage counter to DISTANCE here
  crawler-monitor units NAME m|ft            footage in metres or feet
  crawler-monitor direction NAME downstream|upstream
  crawler-monitor mark NAME CODE [--clock H] [--start|--finish] [--note TEXT]
                                    stamp an observation at the current distance
  crawler-monitor status NAME                the daemon's status (NAME may be * for every crawler)
  crawler-monitor observations NAME          the run's observations (NAME may be *)

Zenoh flags (any command): --connect EP, --listen EP (repeatable), --zenoh-mode peer|client|router,
--zenoh-config FILE, --no-multicast; the same as crawlerd's. Default: peer with multicast scouting,
which finds crawlers on the same network by itself.

The live view (rich) redraws in place on a terminal; on a pipe it prints one line per update instead.
plot, report, the live view, MCAP and Foxglove need the laptop's extra: pip install 'crawlerd[monitor]'.
Exit status: 0 done (Ctrl-C and SIGTERM end a watch cleanly), 1 no crawler answered / the crawler
refused / zenoh failed / a missing package, 2 bad arguments or an unreadable file.
docs/operator.md has the details.
"""

from .cli import main

__all__ = ["main"]
