"""hw_sim: a ray-cast pipe-wall camera simulator with exact ground truth.

The independent instrument that crawlerd's odometry is measured with: it shares the conventions of
docs/conventions.md with `crawler/` but no code. See docs/simulator.md.

    from hw_sim import SimConfig, Simulator, write_run, read_ground_truth
    sim = Simulator(SimConfig(tilt_deg=24, speed_m_s=0.2, duration_s=5))
    for f in sim.frames():
        f.index, f.t_s, f.image, f.distance_m, f.speed_m_s
"""
from .config import BadValue, ConfigError, SimConfig, SimError
from .io import read_ground_truth, read_h264, read_pts, write_run
from .render import Frame, Simulator

__all__ = ["BadValue", "ConfigError", "Frame", "SimConfig", "SimError", "Simulator", "read_ground_truth",
           "read_h264", "read_pts", "write_run"]
