# Copyright 2026 physdyn_ros maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""The simulation core (pybullet, DIRECT): one object on a plane, random pushes, re-simulation from a state.

`physdyn_ros.sim.generate` (the `physdyn generate` command; its steps in `physdyn_ros.sim.generation`) is
imported on its own, not from here.
"""
from .push import NUM_FRAMES, PushConfig, random_scale, record, sample_impulse, simulate_from_state, simulate_push
from .simulator import SimConfig, Simulator, convex_decomposition, tilt_angle

__all__ = ["NUM_FRAMES", "PushConfig", "SimConfig", "Simulator", "convex_decomposition", "random_scale", "record",
           "sample_impulse", "simulate_from_state", "simulate_push", "tilt_angle"]
