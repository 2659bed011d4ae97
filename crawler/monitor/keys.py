"""Keys in the live view: `m` marks an observation, `q` quits. Stdlib termios/tty, nothing else.

`MarkPrompt` is pure (characters in, actions out), so the tests type at it; `Keyboard` only switches a
real terminal to cbreak mode (no echo, a key at a time, Ctrl-C still a signal) and reads what is there
without blocking. On anything that is not a terminal (a pipe, /dev/null, CI) it reads nothing, ever.
"""

from __future__ import annotations

import os
import select
from dataclasses import dataclass

from .commands import KINDS, mark_args

ENTER, ESC, TAB, BACKSPACES = ("\r", "\n"), "\x1b", "\t", ("\x7f", "\b")
HELP = "m mark   q quit   Ctrl-C quits"


@dataclass(frozen=True)
class Mark:
    """Send `mark` with these checked arguments to crawler `name`."""

    name: str
    args: dict


@dataclass(frozen=True)
class Quit:
    pass


def parse_mark(line: str) -> dict:
    """`CODE [@CLOCK] [start|finish] [note ...]` -> the mark arguments (ValueError names the bad word)."""
    words = line.split()
    if not words:
        raise ValueError("type a code first, e.g. FL @3 start crack at the joint")
    code, clock, kind, rest = words[0], None, "point", words[1:]
    while rest:
        word = rest[0].lower()
        if word.startswith("@"):
            clock = rest.pop(0)
        elif word in KINDS or word in ("s", "f"):
            kind = {"s": "start", "f": "finish"}.get(word, word)
            rest.pop(0)
        else:
            break
    return mark_args(code, clock, kind, " ".join(rest))


class MarkPrompt:
    """The one-line prompt after `m`: Tab picks the crawler, Enter sends, Esc cancels."""

    def __init__(self):
        self.active = False
        self.buffer = ""
        self.target: str | None = None
        self.error = ""

    def feed(self, text: str, names: list[str]) -> list:
        """Characters typed -> actions (Mark, Quit); the prompt line changes as a side effect."""
        actions = []
        for ch in text:
            action = self._key(ch, names)
            if action is not None:
                actions.append(action)
        return actions

    def _key(self, ch: str, names: list[str]):
        if not self.active:
            if ch == "q":
                return Quit()
            if ch == "m":
                if not names:
                    self.error = "no crawler to mark yet"
                    return None
                self.active, self.buffer, self.error = True, "", ""
                if self.target not in names:
                    self.target = names[0]
            return None
        if ch == ESC:
            self.active, self.error = False, ""
        elif ch == TAB and names:
            i = names.index(self.target) if self.target in names else -1
            self.target = names[(i + 1) % len(names)]
        elif ch in BACKSPACES:
            self.buffer = self.buffer[:-1]
        elif ch in ENTER:
            return self._submit()
        elif ch.isprintable():
            self.buffer += ch
        return None

    def _submit(self):
        try:
            args = parse_mark(self.buffer)
        except ValueError as exc:
            self.error = str(exc)
            return None
        self.active, self.buffer, self.error = False, "", ""
        return Mark(self.target, args)

    def line(self) -> str:
        """What the view shows: the prompt while typing, else the last complaint (or nothing)."""
        if self.active:
            tail = f"   !! {self.error}" if self.error else ""
            return (f"mark {self.target}> {self.buffer}_{tail}   CODE [@CLOCK] [start|finish] [note]; Enter "
                    "sends, Tab: next crawler, Esc: cancel")
        return f"!! {self.error}" if self.error else ""


class Keyboard:
    """cbreak mode on a terminal's stdin for the life of the `with`; read() never blocks."""

    def __init__(self, fd: int | None = None):
        self.fd = fd
        self._saved = None

    def __enter__(self):
        import sys
        import termios
        import tty

        fd = self.fd if self.fd is not None else _fileno(sys.stdin)
        if fd is None or not os.isatty(fd):
            self.fd = None
            return self
        self.fd = fd
        try:
            self._saved = termios.tcgetattr(fd)
            tty.setcbreak(fd)
        except termios.error:
            self.fd = self._saved = None
        return self

    @property
    def enabled(self) -> bool:
        return self.fd is not None

    def read(self) -> str:
        if self.fd is None:
            return ""
        try:
            ready, _, _ = select.select([self.fd], [], [], 0)
            return os.read(self.fd, 256).decode("utf-8", "ignore") if ready else ""
        except OSError:             # the terminal went away: stop reading it
            self.fd = None
            return ""

    def __exit__(self, *exc):
        import termios

        if self._saved is not None and self.fd is not None:
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)
        self._saved = None


def _fileno(stream):
    try:
        return stream.fileno()
    except (AttributeError, ValueError, OSError):   # pytest's captured stdin, a closed stream
        return None
