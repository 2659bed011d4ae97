"""The ARM yardstick: what a frame costs on the Raspberry Pi's own instruction set.

Runs Python code on a Debian bookworm armhf userland (the distribution's python3.11, numpy 1.24 and
OpenCV 4.6, as Raspberry Pi OS 32-bit ships them) under qemu-arm with armcount, a plugin that counts
the ARM instructions executed, split by stage and by library (benchmarks/armhf/). `setup` there builds
or reuses the userland. Used by benchmarks/throughput.py --arm; see docs/performance.md.

Host side: ensure(), run(). Guest side (inside qemu): Stages marks which stage the code is in with a
system call that does not exist (syscall 0xC0DE, stage): about 2.6 k instructions per switch.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
ARMHF = HERE / "armhf"
STAGE_SYSCALL = 0xC0DE
PI2_HZ = 900e6
PI2_IPC = 0.5

# library file name prefixes -> the groups a breakdown reports
LIB_GROUPS = (("libopencv", "OpenCV"), ("cv2.", "OpenCV"), ("libtbb", "OpenCV"),
              ("_multiarray", "numpy"), ("_umath", "numpy"), ("libblas", "numpy"), ("liblapack", "numpy"),
              ("libopenblas", "numpy"), ("python3", "Python"), ("libc.so", "libc/libm"),
              ("libm.so", "libc/libm"), ("libstdc++", "libc/libm"), ("libgcc", "libc/libm"),
              ("libav", "FFmpeg"), ("libsw", "FFmpeg"), ("libx264", "FFmpeg"))


def pi2_fps(instructions_per_frame: float) -> float:
    """Frames per second on one 900 MHz Cortex-A7 core at IPC 0.5."""
    return PI2_HZ * PI2_IPC / instructions_per_frame


def lib_group(name: str) -> str:
    for prefix, group in LIB_GROUPS:
        if name.startswith(prefix):
            return group
    return "other"


def cache_dir() -> Path:
    """Where setup puts the userland and the plugin (the same place as benchmarks/armhf/setup)."""
    if os.environ.get("ARMHF_CACHE"):
        return Path(os.environ["ARMHF_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "crawlerd-armhf"


def ensure() -> Path:
    """Build or reuse the armhf userland and the plugin; returns the userland's root."""
    root = Path(os.environ.get("ARMROOT") or cache_dir() / "root")
    plugin = cache_dir() / "armcount.so"
    import hashlib

    want = hashlib.sha256((ARMHF / "armcount.c").read_bytes()).hexdigest()
    stamp = plugin.with_name(plugin.name + ".sha256")
    fresh = stamp.exists() and stamp.read_text().strip() == want
    if not (root / "usr/bin/python3.11").exists() or not plugin.exists() or not fresh:
        p = subprocess.run([str(ARMHF / "setup")], env=dict(os.environ, ARMROOT=str(root)))
        if p.returncode:
            raise SystemExit(f"arm yardstick: benchmarks/armhf/setup failed (exit {p.returncode})")
    return root


@dataclass
class Counts:
    """ARM instructions of one run: the total and a {stage: {library: n}} split."""

    total: int
    split: dict[int, dict[str, int]] = field(default_factory=dict)
    stdout: str = ""
    children: list["Counts"] = field(default_factory=list)    # forked processes, each on its own

    def stage(self, s: int) -> int:
        return sum(self.split.get(s, {}).values())

    def grouped(self, s: int) -> dict[str, int]:
        out: dict[str, int] = {}
        for lib, n in self.split.get(s, {}).items():
            out[lib_group(lib)] = out.get(lib_group(lib), 0) + n
        return out


def parse_counts(text: str) -> Counts:
    c = Counts(0)
    for line in text.splitlines():
        f = line.split()
        if f[:1] == ["stage"]:
            c.split.setdefault(int(f[1]), {})[" ".join(f[2:-1])] = int(f[-1])
        elif f[:1] == ["total"]:
            c.total = int(f[1])
    return c


def run(args: list[str], cwd: Path = ROOT, quiet: bool = True, tries: int = 2) -> Counts:
    """Runs `python3.11 ARGS` on the armhf userland (via benchmarks/armhf/count) and counts it.

    qemu-user now and then deadlocks a multi-threaded guest (PyAV's decoding threads, seen twice in
    a few dozen runs): a run that takes longer than ARMCOUNT_TIMEOUT_S (900 s; the longest
    benchmark run takes about 3 minutes) is killed and started again, once."""
    ensure()
    timeout = float(os.environ.get("ARMCOUNT_TIMEOUT_S", "900"))
    with tempfile.NamedTemporaryFile("r", suffix=".armcount") as out:
        env = dict(os.environ, ARMCOUNT_OUT=out.name)
        pipe = subprocess.PIPE if quiet else None
        proc = subprocess.Popen([str(ARMHF / "count"), *args], cwd=cwd, env=env, stdout=pipe, stderr=pipe,
                                text=True, start_new_session=True)
        try:
            stdout, stderr = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            for child in Path(out.name).parent.glob(Path(out.name).name + ".*"):
                child.unlink()
            if tries <= 1:
                raise SystemExit(f"arm yardstick: python3.11 {' '.join(args)} hung (no end in {timeout:g} s)")
            print(f"arm yardstick: a run hung under qemu after {timeout:g} s; starting it again", file=sys.stderr)
            return run(args, cwd, quiet, tries - 1)
        p = subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)
        if p.returncode:
            tail = (p.stderr or "")[-2000:] if quiet else ""
            raise SystemExit(f"arm yardstick: python3.11 {' '.join(args)} failed (exit {p.returncode})\n{tail}")
        counts = parse_counts(Path(out.name).read_text())
        counts.stdout = p.stdout or ""
        for child in sorted(Path(out.name).parent.glob(Path(out.name).name + ".*")):
            counts.children.append(parse_counts(child.read_text()))
            child.unlink()
        return counts


def slope(short: Counts, long: Counts, frames: int) -> float:
    """Instructions per frame between a short and a long run (start-up cancels)."""
    return (long.total - short.total) / frames


# -- guest side --------------------------------------------------------------------------------------

class Stages:
    """Inside qemu: attributes the instructions of wrapped functions to numbered stages.

    Wrappers nest: a stage ends by going back to the one it interrupted.
    """

    def __init__(self):
        import ctypes

        self._syscall = ctypes.CDLL(None, use_errno=True).syscall
        self.current = 0

    def set(self, stage: int):
        self.current = stage
        self._syscall(STAGE_SYSCALL, stage)

    def wrap(self, owner, name: str, stage, keep=()):
        """Counts owner.name as `stage` (an int, or a callable giving one per call), except when
        called from one of the stages in `keep`."""
        fn = getattr(owner, name)

        def marked(*a, **kw):
            prev = self.current
            if prev in keep:
                return fn(*a, **kw)
            self.set(stage() if callable(stage) else stage)
            try:
                return fn(*a, **kw)
            finally:
                self.set(prev)

        setattr(owner, name, marked)
        return fn
