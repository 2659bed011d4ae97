"""The measuring loop: frames in, estimates out to every output, operator commands in between.

It sees only ports (crawler/ports.py): a frame source, the LEDs and one list of outputs, plus the
queue the network hands commands through. crawler/service.py builds them; the same loop runs the
live camera, the simulator and recordings. The loop owns all state; other threads only queue
commands for it.
"""

from __future__ import annotations

import logging
import math
import time
import uuid
from collections import deque

from .errors import CrawlerError
from .distance import DistanceChain
from .gaps import GapBridge
from .inspection import Inspection
from .wheel.port import NoWheel
from .leds import NoLeds
from .commands import CommandQueue, CommandRefused, number
from .odometry import Odometer
from .stats import RunStats

_log = logging.getLogger(__name__)
FPS_WINDOW = 60          # frames the status's fps is averaged over


INSPECTION_COMMANDS = ("zero", "preset", "units", "direction", "mark", "observations")
COMMANDS = ("reset", "led", *INSPECTION_COMMANDS)


def new_run_id() -> str:
    return uuid.uuid4().hex[:12]


def measure_serially(odometer: Odometer, frames):
    """(frame, estimate) of each frame as it comes, in this process ([odometry] workers = 1; the
    pipeline of crawler/workers.py yields the same pairs, a few frames later)."""
    for frame in frames:
        yield frame, odometer.update(frame.gray, frame.t_s, frame.intra)


def _resumed_inspection(resume: dict | None, fresh: Inspection) -> Inspection:
    """The footage counter and observations the checkpoint kept, else a fresh start."""
    if not resume or "inspection" not in resume:
        return fresh
    try:
        return Inspection.from_dict(resume["inspection"])
    except (ValueError, TypeError, AttributeError) as exc:
        _log.error("the checkpoint's footage counter and observations are unreadable (%s); starting them "
                   "afresh (the distance is kept)", exc)
        return fresh


class Daemon:
    """One measurement run: light up, measure every frame, hand it to the outputs, answer commands."""

    def __init__(self, source, odometer: Odometer, *, name: str, leds=None, outputs=(),
                 commands: CommandQueue | None = None, resume: dict | None = None,
                 inspection: Inspection | None = None, chain: DistanceChain | None = None, wheel=None,
                 clock=time.monotonic, stop=lambda: False, max_frames: int | None = None, restart=None,
                 measure=None):
        self.source = source
        self.odometer = odometer
        self.measure = measure or (lambda frames: measure_serially(odometer, frames))
        self.name = name
        self.leds = leds or NoLeds()
        self.outputs = list(outputs)
        self.commands = commands or CommandQueue()
        self.clock = clock
        self.stop = stop
        self.max_frames = max_frames
        self.run_id = resume["run_id"] if resume else new_run_id()
        self._resume_m = resume["distance_m"] if resume else 0.0
        self.restart = restart             # RestartGap of a resumed run (restart.py), else None
        self.unmeasured_s = float((resume or {}).get("unmeasured_s") or 0.0)
        self._resume_tilt = (resume or {}).get("tilt")     # tilt auto's estimate before the restart
        self._reference_at = None          # (reference_seq, published distance) of the odometer's reference
        self.inspection = _resumed_inspection(resume, inspection or Inspection())
        self.chain = chain or DistanceChain(GapBridge(distance_m=self._resume_m))
        self.wheel = wheel or NoWheel()
        self._published_m = self._resume_m     # the distance the last frame published
        self._last_t = 0.0
        self.stats = RunStats()
        self.started = 0.0
        self.last_error: str | None = None
        self._frame_times: list[float] = []
        self._drops: deque[int] = deque(maxlen=FPS_WINDOW)   # frames the source dropped before each
        self._last_index: int | None = None
        self._received = 0.0                  # when the newest frame came from the source
        self._last_est = None

    # -- what outputs may ask (ports.Run) -------------------------------------------------------------

    @property
    def distance_m(self) -> float:
        return self._published_m

    def state(self) -> dict:
        return {"distance_m": round(self.distance_m, 6), "frames": self.stats.frames, "run_id": self.run_id,
                "inspection": self.inspection.to_dict(), "unmeasured_s": round(self._unmeasured(), 3),
                **self.chain.state(), **self.odometer.pose.checkpoint()}

    def reference(self):
        """(seq, ROI image, meta) of the frame a restart would measure against, or None."""
        ref, at = self.odometer.reference, self._reference_at
        if ref is None or at is None or at[0] != self.odometer.reference_seq:
            return None
        return at[0], ref[0], {"distance_m": round(at[1], 6), "lateral_m": round(ref[2], 6),
                               "roi": list(self.odometer.roi)}

    def _unmeasured(self) -> float:
        return self.unmeasured_s + (self.restart.unmeasured_s if self.restart else 0.0)

    def describe(self, estimate) -> dict:
        """An estimate as the outputs publish it: with the crawler, the run and the footage counter."""
        return dict(estimate.as_dict(), name=self.name, run_id=self.run_id,
                    unmeasured_s=round(self._unmeasured(), 3), **self.inspection.fields(estimate.distance_m),
                    **self.odometer.pose.frame())

    def status(self) -> dict:
        win = self._frame_times
        fps = (len(win) - 1) / (win[-1] - win[0]) if len(win) > 1 and win[-1] > win[0] else 0.0
        est = self._last_est
        out = {
            "name": self.name, "source": self.source.kind, "source_detail": self.source.description,
            "fps": round(fps, 2), "frames": self.stats.frames,
            "dropped_frames": self.stats.dropped, "drop_rate": self._drop_rate(),
            "tracks": est.inliers if est else 0, "tracking": bool(est and est.tracking),
            "distance_m": round(self.distance_m, 6),
            "led_level": round(float(self.leds.level), 3),
            "uptime_s": round(self.clock() - self.started, 3),
            "last_error": self.last_error,
            "run_id": self.run_id,
            "loop_ms": self.stats.loop.as_dict(),
            "observations": len(self.inspection.observations),
            "sigma_m": None if est is None or est.sigma_m is None else round(est.sigma_m, 6),
            "bridged": bool(est and est.bridged), "distance_source": est.source if est else None,
            "slip": bool(est and est.slip), "slips": self._slips(), "wheel": self.wheel.description,
            "unmeasured_s": round(self._unmeasured(), 3),
            "restart": self.restart.as_dict() if self.restart else None,
            **self.inspection.fields(self.distance_m), **self.odometer.pose.status(),
        }
        info = self.source.info()
        if info:
            out["camera"] = info
        for output in self.outputs:
            output.report(out)
        return out

    # -- control --------------------------------------------------------------------------------------

    def handle(self, request: dict) -> dict:
        """A command, run in the frame loop. Raises CommandRefused for one that cannot be run."""
        cmd = request.get("cmd")
        if cmd == "reset":
            if math.isfinite(self.odometer.distance):
                self.odometer.set_distance(0.0)
            else:                              # whatever state it is in, a reset starts clean
                self.odometer.reset(distance=0.0)
            self.chain.set_distance(0.0, vision_m=0.0)
            self._published_m = 0.0
            self.unmeasured_s, self.restart = 0.0, None
            self.run_id = new_run_id()
            self.inspection.new_run()
            for output in self.outputs:
                output.reset(self)
            _log.info("distance reset by operator; new run %s", self.run_id)
            return {"cmd": "reset", "distance_m": 0.0, "run_id": self.run_id}
        if cmd == "led":
            level = number(request, "level", 0.0, 1.0)
            self.leds.set(level)
            return {"cmd": "led", "level": level}
        if cmd == "status":
            return self.status()
        if cmd in INSPECTION_COMMANDS:
            reply, observation = self.inspection.command(cmd, request, self.distance_m, self._last_t, self.run_id)
            if observation is not None:
                _log.info("observation %s %s at %.3f m", observation["id"], observation["code"], self.distance_m)
                for output in self.outputs:
                    output.note("observations", observation)
            return reply
        raise CommandRefused(f"unknown command {cmd!r}; the commands are {', '.join(COMMANDS)}")

    # -- the loop -------------------------------------------------------------------------------------

    def run(self) -> RunStats:
        """Measure until the source ends, stop() is true, or a fault; returns the run's statistics.

        A source that breaks mid-way ends the run with the error recorded in the stats and the status
        (what was measured up to the break is kept). Lights go off and every output has its last word
        (checkpoint, final status, STOPPING) whatever happens, a crash included.
        """
        self.started = self.clock()
        mount = self.odometer.pose.resume(self._resume_tilt)
        if mount is not None:
            self.odometer.remount(mount)
            _log.warning("tilt auto resumes at %.2f deg, the estimate before the restart",
                         math.degrees(mount.mount.tilt_rad))
        if self.restart is not None:
            _log.warning("resuming run %s at %.4f m after %.1f s down", self.run_id, self._resume_m,
                         self.restart.down_s)
        elif self._resume_m:
            self.odometer.reset(distance=self._resume_m)
            _log.warning("resuming run %s at %.4f m", self.run_id, self._resume_m)
        for output in self.outputs:
            output.start(self)
        self.leds.on()
        try:
            for frame, est in self.measure(self._timed(self.source.frames())):
                if self.stop():                   # a stop signal during start-up: no frame at all
                    break
                self._step(frame, est)
                if self.stop() or (self.max_frames and self.stats.frames >= self.max_frames):
                    break
        except CrawlerError as exc:
            self.last_error = self.stats.error = str(exc)
            _log.debug("run ended: %s", exc)          # the caller reports it, once
        finally:
            self.stats.wall_s = self.clock() - self.started
            self.leds.off()
            self._last_words()
        return self.stats

    def _timed(self, frames):
        """The source's frames, noting when each came (the loop's latency counts from there)."""
        for frame in frames:
            self._received = time.perf_counter()
            if self.restart is not None and self.stats.frames == 0 and self.restart.open:
                self._begin_restart(frame.t_s)
            yield frame

    def _count_drops(self, index: int):
        """Gaps in the source's numbering: frames it dropped (the loop was late) or lost."""
        gap = 0 if self._last_index is None else max(0, index - self._last_index - 1)
        self._last_index = index
        self._drops.append(gap)
        self.stats.dropped += gap

    def _drop_rate(self) -> float:
        """The share of the source's frames dropped over the last FPS_WINDOW measured ones."""
        dropped = sum(self._drops)
        return round(dropped / (len(self._drops) + dropped), 4) if self._drops else 0.0

    def _step(self, frame, measured):
        self._observe_restart(measured)
        est = self.chain.update(measured, self.wheel.read(), frame.qp)
        est.frame = frame.index               # the source's numbering (dropped and lost frames leave gaps)
        self._count_drops(frame.index)
        self._published_m = est.distance_m
        if self.odometer.reference_seq != (self._reference_at or (None,))[0]:
            self._reference_at = (self.odometer.reference_seq, est.distance_m)
        self._last_t = frame.t_s
        if self.chain.fusion is not None:
            for note in self.chain.fusion.pop_notes():
                _log.warning("wheel: %s", note)
        if self.chain.last_event is not None:
            event, self.chain.last_event = self.chain.last_event, None
            _log.warning("wheel slip: %s", event.as_dict())
            for output in self.outputs:
                output.note("events", {"event": "slip", **event.as_dict()})
        self._last_est = est
        self.stats.add(est)
        self._frame_times.append(self.clock())
        if len(self._frame_times) > FPS_WINDOW:
            del self._frame_times[0]
        self.commands.drain(self.handle)
        for output in self.outputs:
            output.write(frame, est, self)
        self.stats.loop.add((time.perf_counter() - self._received) * 1000.0)

    def _begin_restart(self, t_s: float):
        """Before the first frame is measured: the odometer starts from the frame saved before the restart."""
        self.restart.begin(self.odometer, t_s)
        if not self.restart.open:
            self._restart_settled(self.restart)

    def _observe_restart(self, raw):
        """Across a restart the first frames are measured against the saved one; the gap settles."""
        gap = self.restart
        if gap is None or not gap.open:
            return
        shift = gap.observe(raw)
        if shift:
            self.chain.bridge.offset_m += shift
        if not gap.open:
            self._restart_settled(gap)

    def _restart_settled(self, gap):
        if gap.state == "measured":
            _log.warning("restart gap of %.1f s measured across: %+.4f m", gap.down_s, gap.measured_m)
        elif gap.state == "wheel":
            _log.warning("restart gap of %.1f s not seen by the camera: the wheel carries it", gap.down_s)
        else:
            _log.warning("restart gap of %.1f s not seen by the camera: its distance is unknown "
                         "(unmeasured_s in every message)", gap.down_s)

    def _last_words(self):
        """Every output's stop(), even when one of them fails: the checkpoint must not wait on the net."""
        for output in self.outputs:
            try:
                output.stop(self)
            except Exception:
                _log.exception("%s failed to stop", type(output).__name__)

    def _slips(self) -> list:
        f = self.chain.fusion
        return [] if f is None else [e.as_dict() for e in f.events]

    def summary(self) -> dict:
        """The closing JSON line."""
        out = self.stats.summary(self.distance_m, self.odometer.lateral)
        if self.odometer.pose.active:
            out["pose"] = self.odometer.pose.status()
        codec = self.chain.codec
        if codec.qp is not None:       # a compressed recording: what its quantiser added to sigma
            out["codec"] = {"mean_qp": round(codec.qp, 2), "keyframes": codec.keyframes,
                            "sigma_m": round(codec.sigma_m, 6)}
        drive = self.chain.bridge.drive.to_dict()      # the rates the gap model takes for what it hides
        if any(r is not None for r in drive.values()):
            out["drive"] = {k: None if r is None else round(r, 3) for k, r in drive.items()}
        for output in self.outputs:
            output.summarize(out)
        return out
