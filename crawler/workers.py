"""Tracking on several cores ([odometry] workers = N): N - 1 worker processes track frames against
their keyframe while this process does what has to happen in order.

A frame's tracks (LK of the keyframe's features into it, from a predicted guess: two thirds of its
cost, docs/performance.md) depend only on the keyframe, the frame and the guess. So the workers take
frames in turn, and the main process keeps the camera, each frame's consensus, keyframe renewals,
rescues and coarse guesses, in frame order, and the outputs. Up to `depth` frames are in flight: a
frame goes to a worker as it comes, with the guess the odometer makes for its time then, and is
measured `depth - 1` frames later. A keyframe renewed meanwhile makes those requests stale: they are
sent again against the new keyframe. The pool is the Odometer's tracker port: the first tracking of
a frame against the keyframe it was sent with comes from its worker; anything else (the coarse-guess
retry, a rescue, a stale or dead worker) is tracked here, with the same function.

Frames and keyframes pass through one anonymous shared mapping made before the workers are forked,
never pickled: `depth` frame slots and a ring of keyframe slots. A request is 36 bytes on a pipe, a
result a few hundred. Nothing outlives the processes (no named segment to leak on a SIGKILL), and a
worker whose parent is gone sees its pipe close and exits. Fork, because the workers inherit the
mapping, and because it is what qemu-user (the ARM yardstick) runs; before forking, OpenCV is set to
one thread (the processes are the parallelism, and a child must never enter a thread pool whose
threads stayed in the parent).
"""

from __future__ import annotations

import gc
import logging
import mmap
import multiprocessing
import signal
import struct
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from .keyframe import track_visible
from .ports import Frame, Output

_log = logging.getLogger(__name__)
REQUEST = struct.Struct("<qqidd")       # seq, keyframe generation, frame slot, step, lateral
RESULT = struct.Struct("<qii")          # seq, tracks (then int32 indices, float32 positions), visible
STALE = -1                              # `visible` of a request whose keyframe was replaced
KEYFRAME_SLOTS = 4                      # a stale request may still read the one before last
REPLY_WAIT_S = 10.0                     # a worker that takes longer than this to answer is hung


class KeyframeView:
    """What track_visible reads of a keyframe, as views of its shared slot."""

    def __init__(self, seen, pts, model, flat: bool):
        self.seen, self.pts, self.model, self.flat = seen, pts, model, flat


class SharedRing:
    """The layout of the shared mapping: the newest keyframe generation, frame slots, keyframe slots."""

    def __init__(self, frame_shape, roi, max_features: int, frames: int):
        h, w = frame_shape
        rh, rw = roi[3], roi[2]
        n = max_features
        self.roi = tuple(roi)
        sizes = [8] + [h * w] * frames + [24 + rh * rw + 8 * n + 24 * n] * KEYFRAME_SLOTS
        offsets = np.cumsum([0] + [-(-s // 16) * 16 for s in sizes])
        self.mm = mmap.mmap(-1, int(offsets[-1]))         # anonymous and shared: forks see it
        view = lambda shape, dtype, off: np.ndarray(shape, dtype, self.mm, int(off))   # noqa: E731
        self.latest = view((1,), np.int64, offsets[0])
        self.frames = [view((h, w), np.uint8, offsets[1 + i]) for i in range(frames)]
        self.slots = []
        for i in range(KEYFRAME_SLOTS):
            off = offsets[1 + frames + i]
            self.slots.append((view((3,), np.int64, off), view((rh, rw), np.uint8, off + 24),
                               view((n, 2), np.float32, off + 24 + rh * rw),
                               view((2 * n, 3), np.float32, off + 24 + rh * rw + 8 * n)))
        self.latest[0] = -1

    def publish(self, gen: int, kf) -> None:
        """Keyframe generation `gen` into its slot, then announced (a reader checks the slot's tag)."""
        tag, img, pts, model = self.slots[gen % KEYFRAME_SLOTS]
        n = len(kf.pts)
        tag[0] = -1
        img[...] = kf.seen
        pts[:n] = kf.pts
        model[:2 * n] = kf.model
        tag[1], tag[2] = n, kf.flat
        tag[0] = gen
        self.latest[0] = gen

    def keyframe(self, gen: int) -> KeyframeView | None:
        tag, img, pts, model = self.slots[gen % KEYFRAME_SLOTS]
        if tag[0] != gen:
            return None
        n = int(tag[1])
        return KeyframeView(img, pts[:n], model[:2 * n], bool(tag[2]))

    def holds(self, gen: int) -> bool:
        return self.slots[gen % KEYFRAME_SLOTS][0][0] == gen

    def roi_of(self, slot: int) -> np.ndarray:
        x, y, w, h = self.roi
        return self.frames[slot][y:y + h, x:x + w]


def serve(conn, ring: SharedRing, view, params, close=(), initializer=None, number: int = 0) -> None:
    """A worker's loop: requests in, tracks out, until the pipe says stop (b"") or closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)      # Ctrl-C is the main process's to handle
    signal.signal(signal.SIGTERM, signal.SIG_DFL)     # systemd's stop: go at once
    for c in close:
        c.close()
    if initializer is not None:
        initializer(number)
    boxes = {}
    while True:
        try:
            msg = conn.recv_bytes()
        except (EOFError, OSError):
            return
        if not msg:
            return
        seq, gen, slot, step, lat = REQUEST.unpack(msg)
        kf = ring.keyframe(gen) if ring.latest[0] == gen else None
        if kf is None:
            conn.send_bytes(RESULT.pack(seq, 0, STALE))
            continue
        n = len(kf.pts)
        if n not in boxes:
            boxes[n] = tuple(np.tile(a, (n, 1)) for a in view)
        idx, pts, visible = track_visible(kf, ring.roi_of(slot), step, lat, boxes[n], params)
        if not ring.holds(gen):                       # overwritten while we read it
            visible = STALE
        conn.send_bytes(RESULT.pack(seq, len(idx), visible) + idx.astype(np.int32).tobytes()
                        + pts.astype(np.float32).tobytes())


@dataclass
class _Entry:
    """A frame in flight: the frame (its grey plane the ring's slot), and the request that tracks it."""

    frame: Frame
    slot: int
    gen: int = -1               # the keyframe generation it was sent with (-1: not sent)
    seq: int = -1
    worker: int = -1
    used: bool = False


class _Worker:
    def __init__(self, number, process, conn):
        self.number, self.process, self.conn = number, process, conn
        self.alive = True
        self.outstanding = 0


class TrackerPool:
    """`workers - 1` tracking processes for one Odometer: `with TrackerPool(odo, shape, 4) as pool:
    for frame, estimate in pool.measure(frames): ...` (what the Daemon's `measure` port takes)."""

    def __init__(self, odometer, frame_shape, workers: int, depth: int | None = None, initializer=None):
        if workers < 2:
            raise ValueError(f"a tracker pool needs workers >= 2, not {workers}")
        self.odometer = odometer
        self.depth = depth or workers
        self.processes = workers - 1
        self.ring = SharedRing(frame_shape, odometer.roi, odometer.params.flow.max_features, self.depth)
        self.initializer = initializer
        self.counts = {"tracked_by_workers": 0, "tracked_here": 0, "sent": 0, "resent": 0, "stopped": 0}
        self._workers: list[_Worker] = []
        self._free = list(range(self.depth))
        self._pending: deque[_Entry] = deque()
        self._current: _Entry | None = None
        self._published, self._gen, self._seq, self._next = None, -1, 0, 0
        self._ready: dict[int, bytes] = {}
        self._cv_threads = None

    # -- lifetime ---------------------------------------------------------------------------------------

    def __enter__(self) -> "TrackerPool":
        import cv2

        self._cv_threads = cv2.getNumThreads()
        cv2.setNumThreads(1)
        ctx = multiprocessing.get_context("fork")
        gc.collect()
        gc.freeze()                 # the workers' collector then leaves the inherited heap unwritten
        try:
            for i in range(self.processes):
                mine, theirs = ctx.Pipe()
                close = [w.conn for w in self._workers] + [mine]
                p = ctx.Process(target=serve, name=f"crawlerd-tracker-{i + 1}", daemon=True,
                                args=(theirs, self.ring, self.odometer.view, self.odometer.params.flow, close,
                                      self.initializer, i + 1))
                p.start()
                theirs.close()
                self._workers.append(_Worker(i, p, mine))
        except BaseException:
            self.close()
            raise
        finally:
            gc.unfreeze()
        self.odometer.tracker = self
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        import cv2

        self.odometer.tracker = track_visible
        if self._cv_threads is not None:
            cv2.setNumThreads(self._cv_threads)
        for w in self._workers:
            try:
                w.conn.send_bytes(b"")
            except OSError:
                pass
        for w in self._workers:
            w.process.join(timeout=2.0)
            if w.process.is_alive():
                w.process.terminate()
                w.process.join(timeout=2.0)
            w.conn.close()
        self._workers = []

    @property
    def alive(self) -> int:
        return sum(w.alive for w in self._workers)

    @property
    def pids(self) -> list[int]:
        return [w.process.pid for w in self._workers]

    # -- the pipeline -----------------------------------------------------------------------------------

    def measure(self, frames):
        """(frame, estimate) per frame, in order, `depth - 1` frames after it came. A yielded frame's
        pixels are the pool's copy, valid until the next pair is asked for."""
        try:
            for frame in frames:
                self._pending.append(self._admit(frame))
                if len(self._pending) >= self.depth:
                    yield from self._process_oldest()
            while self._pending:
                yield from self._process_oldest()
        finally:                    # a run that stops early leaves frames in flight: forget them
            self._pending.clear()
            self._ready.clear()
            self._free = list(range(self.depth))

    def _process_oldest(self):
        entry = self._pending.popleft()
        self._current = entry
        try:
            frame = entry.frame
            est = self.odometer.update(frame.gray, frame.t_s, frame.intra)
        finally:
            self._current = None
        self._ready.pop(entry.seq, None)        # measured without its worker's tracks (no texture)
        self._sync()
        try:
            yield frame, est
        finally:
            self._free.append(entry.slot)

    def _admit(self, frame) -> _Entry:
        slot = self._free.pop()
        np.copyto(self.ring.frames[slot], frame.gray)      # the camera's buffer goes back at once
        entry = _Entry(Frame(frame.index, frame.t_s, self.ring.frames[slot], frame.qp, frame.intra), slot)
        self._sync()
        self._send(entry)
        return entry

    def _sync(self):
        """After the odometer changed its keyframe: publish the new one and send the frames in
        flight again, against it."""
        kf = self.odometer.keyframe
        if kf is self._published:
            return
        self._published = kf
        if kf is None:
            return
        self._gen += 1
        self.ring.publish(self._gen, kf)
        for entry in self._pending:
            if entry.seq >= 0:
                self.counts["resent"] += 1
            self._send(entry)

    def _send(self, entry: _Entry):
        if self._published is None or not self.alive:
            return
        live = [w for w in self._workers if w.alive]
        w = min(live, key=lambda w: (w.outstanding, (w.number - self._next) % len(self._workers)))
        self._next = w.number + 1
        self._drain(w)
        self._seq += 1
        step, lat = self.odometer.guess(entry.frame.t_s)
        try:
            w.conn.send_bytes(REQUEST.pack(self._seq, self._gen, entry.slot, step, lat))
        except OSError:
            self._lost(w)
            return self._send(entry)
        w.outstanding += 1
        entry.gen, entry.seq, entry.worker, entry.used = self._gen, self._seq, w.number, False
        self.counts["sent"] += 1

    # -- the Odometer's tracker port --------------------------------------------------------------------

    def __call__(self, kf, img, step, lat, view, params):
        e = self._current
        if e is not None and not e.used and e.seq >= 0 and e.gen == self._gen and kf is self._published:
            e.used = True
            found = self._collect(e)
            if found is not None:
                self.counts["tracked_by_workers"] += 1
                return found
        self.counts["tracked_here"] += 1
        return track_visible(kf, img, step, lat, view, params)

    def _collect(self, e: _Entry):
        """The worker's tracks of entry e, or None (stale, or the worker is gone)."""
        reply = self._ready.pop(e.seq, None)
        w = self._workers[e.worker]
        while reply is None and w.alive:
            try:
                if not w.conn.poll(REPLY_WAIT_S):
                    raise TimeoutError(f"no answer in {REPLY_WAIT_S:g} s")
                msg = w.conn.recv_bytes()
            except (OSError, EOFError, TimeoutError) as exc:
                self._lost(w, exc)
                return None
            w.outstanding -= 1
            seq = RESULT.unpack_from(msg)[0]
            if seq == e.seq:
                reply = msg
            elif self._wanted(seq):
                self._ready[seq] = msg
        if reply is None:
            return None
        _, n, visible = RESULT.unpack_from(reply)
        if visible == STALE:
            return None
        idx = np.frombuffer(reply, np.int32, n, RESULT.size).astype(np.intp)
        pts = np.frombuffer(reply, np.float32, 2 * n, RESULT.size + 4 * n).reshape(n, 2).copy()
        return idx, pts, visible

    def _wanted(self, seq: int) -> bool:
        return any(e.seq == seq and e.gen == self._gen for e in self._pending)

    def _drain(self, w: _Worker):
        """Read what a worker has answered already (results nobody asked for, for frames measured
        without tracking, must not fill its pipe)."""
        try:
            while w.outstanding and w.conn.poll():
                msg = w.conn.recv_bytes()
                w.outstanding -= 1
                seq = RESULT.unpack_from(msg)[0]
                if self._wanted(seq):
                    self._ready[seq] = msg
        except (OSError, EOFError) as exc:
            self._lost(w, exc)

    def _lost(self, w: _Worker, exc=None):
        if not w.alive:
            return
        w.alive = False
        self.counts["stopped"] += 1
        code = w.process.exitcode
        why = f"exit code {code}" if code is not None else (str(exc) or type(exc).__name__)
        _log.error("tracking worker %d stopped (%s); %d of %d left, the rest is tracked in the main process",
                   w.number + 1, why, self.alive, self.processes)
        if w.process.is_alive():
            w.process.terminate()


class WorkersReport(Output):
    """The pool's state in the status and the summary: `workers`."""

    def __init__(self, pool: TrackerPool):
        self.pool = pool

    def report(self, status: dict):
        p = self.pool
        status["workers"] = {"processes": p.processes, "depth": p.depth, **p.counts}

    summarize = report


@contextmanager
def measuring(odometer, frame_shape, workers: int):
    """The Daemon's `measure` port for this many processes: None (the odometer measures in this
    process) for one, else a TrackerPool's, closed on the way out."""
    if workers <= 1:
        yield None
        return
    with TrackerPool(odometer, frame_shape, workers) as pool:
        yield pool.measure
