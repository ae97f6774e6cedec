"""The simulation core (pybullet, DIRECT): one object on a plane, random pushes, re-simulation from a state.

`physdyn_ros.sim.generate` (the `physdyn generate` command; its steps in `physdyn_ros.sim.generation`) is
imported on its own, not from here.
"""
from .push import NUM_FRAMES, PushConfig, random_scale, record, sample_impulse, simulate_from_state, simulate_push
from .simulator import SimConfig, Simulator, convex_decomposition, tilt_angle

__all__ = ["NUM_FRAMES", "PushConfig", "SimConfig", "Simulator", "convex_decomposition", "random_scale", "record",
           "sample_impulse", "simulate_from_state", "simulate_push", "tilt_angle"]
