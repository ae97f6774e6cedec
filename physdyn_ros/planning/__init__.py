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
"""Push planning and online adaptation on top of the dynamics model (numpy + the Predictor; no rclpy; pybullet only
where a planner checks its pushes on the hull, imported then).

    planner.py     PushPlanner: checks a request, runs the search, turns its winner into a PushPlan (or refuses)
    search.py      the search: CEM over Predictor.rollout_batch, the robustness check, the cost of a push
    types.py       the value types: Pose2D, Goal, TableBounds, PlannerConfig, PushPlan, PlanningError
    body.py        mass, inertia and COM-height section of the object: velocity <-> impulse at a contact point
    models.py      the DynamicsModel protocol and AnalyticSlidingModel (closed-form physics stand-in)
    adapt.py       OnlineAdapter: re-predict as observed states arrive ("steps in")
    closed_loop.py plan -> push in the pybullet Simulator -> observe -> re-plan (pybullet imported lazily)
    sim_model.py   PybulletModel: the planner driven by pybullet re-simulation (comparison baseline)
    physics_check.py PhysicsCheck: the finalists re-simulated on the cloud's hull (pybullet, created on use)
    cli.py         `physdyn plan`
"""
from .adapt import OnlineAdapter, repredict
from .body import BodyError, PushBody, body_from_box, body_from_cloud
from .models import AnalyticSlidingModel, DynamicsModel
from .planner import PushPlanner
from .types import Goal, PlannerConfig, PlanningError, Pose2D, PushPlan, TableBounds, wrap_angle, yaw_of

__all__ = ["AnalyticSlidingModel", "BodyError", "DynamicsModel", "Goal", "OnlineAdapter", "PlannerConfig",
           "PlanningError", "Pose2D", "PushBody", "PushPlan", "PushPlanner", "TableBounds", "body_from_box",
           "body_from_cloud", "repredict", "wrap_angle", "yaw_of"]
