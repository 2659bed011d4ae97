"""Exceptions of crawlerd: one root, and each leaf also a builtin so callers can catch either."""

import os
import sys
import traceback


class CrawlerError(Exception):
    """Root of every error crawlerd raises on purpose; its message is meant for the operator."""


class BadConfig(CrawlerError, ValueError):
    """A configuration value is missing, malformed or physically impossible."""


class BadGeometry(BadConfig):
    """The mount, camera and ROI cannot produce a valid measurement (e.g. car wider than the pipe)."""


class VideoError(CrawlerError, IOError):
    """A recording cannot be opened, decoded or timed."""


class CameraUnavailable(CrawlerError, RuntimeError):
    """The CSI camera (or picamera2 itself) cannot be opened."""


def fail(prog: str, exc: BaseException, code: int) -> int:
    """Tell the operator in one line (`prog: error: ...`) and return the exit code.

    CRAWLERD_DEBUG=1 prints the traceback too.
    """
    if os.environ.get("CRAWLERD_DEBUG") == "1":
        traceback.print_exception(exc)
    print(f"{prog}: error: {exc}", file=sys.stderr)
    return code
