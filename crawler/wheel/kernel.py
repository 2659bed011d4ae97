"""The kernel's rotary-encoder driver, read from /dev/input/eventN with python-evdev.

The kernel counts every edge in its interrupt handler; Python runs once per frame, not per edge.
With the overlay's absolute axis (relative_axis off, rollover=1, a large steps) the kernel holds the
position whether anyone has the device open or not, so each read is one EVIOCGABS ioctl (evdev's
`absinfo`) and counts made while crawlerd was down are still there at the next start: the reading
carries the rollover period and the boot's id, and the fusion unwraps across the restart.

A relative axis (relative_axis=1) works too, by draining the queued REL events each frame, but the
input core drops events while nobody has the device open, and its 64-event buffer overflows past
about 30 steps per frame (SYN_DROPPED): counts are lost. Use the absolute axis.
"""

from __future__ import annotations

import errno
import logging
import time
import uuid

from .port import WheelReading, WheelUnavailable

_log = logging.getLogger(__name__)

# linux/input-event-codes.h (stable kernel ABI): kept here so a fake device needs no evdev
EV_SYN, EV_REL, EV_ABS = 0x00, 0x02, 0x03
SYN_DROPPED = 3

INSTALL = ("python-evdev is not installed: on the Pi `sudo apt install python3-evdev` and make the "
           "venv with --system-site-packages (or `pip install 'crawlerd[wheel]'`)")


def read_boot_id() -> str:
    """This boot's id: the kernel's count starts at 0 on every boot."""
    try:
        with open("/proc/sys/kernel/random/boot_id") as f:
            return f.read().strip()
    except OSError:
        return "unknown-boot"


def _evdev():
    try:
        import evdev
    except ImportError:
        raise WheelUnavailable(f"[wheel] backend = \"evdev\": {INSTALL}") from None
    return evdev


def open_input(device: str):
    """An InputDevice for a path (/dev/input/event3, by-path links) or an input device's name."""
    evdev = _evdev()
    try:
        if device.startswith("/"):
            return evdev.InputDevice(device)
        found = []
        for path in evdev.list_devices():
            dev = evdev.InputDevice(path)
            if dev.name == device:
                return dev
            found.append(dev.name)
            dev.close()
    except PermissionError as exc:
        raise WheelUnavailable(f"[wheel] device {exc.filename or device!r}: permission denied; add "
                               "the user to the 'input' group (sudo usermod -aG input USER)") from None
    except OSError as exc:
        raise WheelUnavailable(f"[wheel] device = {device!r} cannot be opened: {exc.strerror}; "
                               "check the overlay line in /boot/firmware/config.txt (docs/wheel.md)") from None
    raise WheelUnavailable(f"[wheel] device = {device!r}: no input device of that name (found: "
                           f"{', '.join(repr(n) for n in found) or 'none'}); is dtoverlay=rotary-encoder "
                           "in /boot/firmware/config.txt? (docs/wheel.md)")


class KernelEncoder:
    """Wheel port on a rotary-encoder input device: one ioctl (or one batch read) per frame."""

    def __init__(self, device: str, counts_per_m: float, *, direction: int = 1, axis: int = 0,
                 clock=time.monotonic, opener=open_input, boot_id=read_boot_id):
        self.device_name, self.axis, self.clock = device, axis, clock
        self._per_count = direction / float(counts_per_m)
        self._opener, self._boot_id = opener, boot_id
        self.dev = None
        self.absolute = True
        self.period_m = None
        self.epoch = None
        self.count = 0               # relative mode: summed events since open
        self.dropped = 0             # relative mode: SYN_DROPPED seen (counts lost)
        self.last_error = None
        self.description = f"kernel rotary-encoder {device!r}"

    @classmethod
    def from_settings(cls, s, *, clock=time.monotonic, opener=open_input, boot_id=read_boot_id):
        return cls(s.device, s.counts_per_m, direction=s.direction, axis=s.axis, clock=clock,
                   opener=opener, boot_id=boot_id)

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    def open(self):
        """Open the device and learn its axis: absolute (position, rollover period) or relative."""
        dev = self._opener(self.device_name)
        caps = dev.capabilities(absinfo=True)
        abs_axes = dict(c for c in caps.get(EV_ABS, []) if isinstance(c, tuple))
        if self.axis in abs_axes:
            info = abs_axes[self.axis]
            steps = info.max - info.min
            self.absolute, self.period_m = True, abs(steps * self._per_count)
            self.epoch = f"{self._boot_id()}:{getattr(dev, 'path', self.device_name)}"
            if steps < 1 << 20:
                _log.warning("%s: the kernel's position wraps every %d counts (%.2f m); set a large "
                             "steps= on the overlay line, e.g. steps=1073741824 (docs/wheel.md)",
                             self.description, steps, self.period_m)
        elif self.axis in caps.get(EV_REL, []):
            self.absolute, self.period_m = False, None
            self.epoch = f"rel:{uuid.uuid4().hex[:12]}"     # counts while closed are lost
            _log.warning("%s has a relative axis: counts made while crawlerd is down are lost; "
                         "use the absolute axis (docs/wheel.md)", self.description)
        else:
            dev.close()
            raise WheelUnavailable(f"[wheel] device {self.device_name!r} has no axis {self.axis} "
                                   f"(its axes: {caps}); set [wheel] axis to the overlay's linux_axis")
        self.dev = dev
        self.description = f"kernel rotary-encoder {dev.name!r} ({'absolute' if self.absolute else 'relative'})"
        return self

    def read(self) -> WheelReading | None:
        """The position now; None (logged once) while the device is gone."""
        dev = self.dev
        if dev is None:
            return None
        try:
            if self.absolute:
                value = dev.absinfo(self.axis).value
            else:
                value = self._drain(dev)
        except OSError as exc:
            if self.last_error is None:
                _log.warning("%s cannot be read (%s); the wheel is left out until it is back",
                             self.description, exc.strerror or exc)
            self.last_error = str(exc)
            if exc.errno == errno.ENODEV:
                self.close()
            return None
        return WheelReading(self.clock(), value * self._per_count, self.period_m, self.epoch)

    def _drain(self, dev) -> int:
        try:
            for ev in dev.read():
                if ev.type == EV_REL and ev.code == self.axis:
                    self.count += ev.value
                elif ev.type == EV_SYN and ev.code == SYN_DROPPED:
                    self.dropped += 1
                    if self.dropped == 1:
                        _log.warning("%s: the event buffer overflowed, counts lost; use the absolute "
                                     "axis (docs/wheel.md)", self.description)
        except BlockingIOError:
            pass
        return self.count

    def close(self):
        dev, self.dev = self.dev, None
        if dev is not None:
            try:
                dev.close()
            except OSError:
                pass
