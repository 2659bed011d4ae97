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


# a module crawlerd needs -> (its Raspberry Pi OS package, what to do on a PC)
PACKAGES = {
    "numpy": ("python3-numpy", "pip install 'crawlerd[pc]'"),
    "cv2": ("python3-opencv", "pip install 'crawlerd[pc]'"),
    "av": ("python3-av", "pip install 'crawlerd[pc]'"),
    "gpiozero": ("python3-gpiozero", "pip install gpiozero"),
    "zenoh": (None, "pip install 'eclipse-zenoh>=1.0'"),
    "evdev": ("python3-evdev", "pip install evdev"),
}


def missing_module(exc: ModuleNotFoundError) -> str:
    """What to install for a module that is not there, in one line."""
    top = (exc.name or "").split(".")[0]
    apt, pc = PACKAGES.get(top, (None, None))
    if apt is None and pc is None:
        return f"Python module {top!r} is missing ({exc})"
    pi = (f"on the Raspberry Pi run 'sudo apt install {apt}' and make the venv with "
          "'python3 -m venv --system-site-packages'" if apt else f"on the Raspberry Pi run '{pc}' in the venv")
    return f"Python module {top!r} is missing: {pi}; on a PC run \"{pc}\" (docs/deploy.md)"


def fail(prog: str, exc: BaseException, code: int) -> int:
    """Tell the operator in one line (`prog: error: ...`) and return the exit code.

    CRAWLERD_DEBUG=1 prints the traceback too.
    """
    if os.environ.get("CRAWLERD_DEBUG") == "1":
        traceback.print_exception(exc)
    print(f"{prog}: error: {exc}", file=sys.stderr)
    return code


ENDINGS = (KeyboardInterrupt, ModuleNotFoundError, CrawlerError)   # how a command line's main() may end


def ended(prog: str, exc: BaseException) -> int:
    """The exit code (and the one line) for how a command ended: a bad input or configuration 2, a
    missing module 2 with what to install, Ctrl-C 130 (one of ENDINGS)."""
    if isinstance(exc, KeyboardInterrupt):
        return 130
    if isinstance(exc, ModuleNotFoundError):
        return fail(prog, CrawlerError(missing_module(exc)), 2)
    return fail(prog, exc, 2)
