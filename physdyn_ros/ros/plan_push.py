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
"""The predictor's plan_push service: a PlanPush request -> the planner's inputs, its PushPlan -> the response.

The node keeps the model, the planner and the buffered features and states; this module reads the request
against the node's parameters, asks the node for the object's shape and pose, and fills the response.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from ..msg import ObjectState
from ..shapes.core import DEFAULT_DENSITY
from ..srv import PlanPush
from .convert import pose, pose_to_numpy, time_to_ns, yaw_quaternion
from .requests import RequestError, check_mass
from .trajectory import trajectory_to_msg

#: The finest position (m) and yaw (rad) tolerance a plan_push request may ask for.
MIN_POSITION_TOLERANCE, MIN_YAW_TOLERANCE = 1e-4, 1e-4
#: s: the longest planning a request may ask for.
MAX_TIME_BUDGET = 30.0


def planner_config(req: PlanPush.Request, param: Callable[[str], Any]):
    """The PlannerConfig of a request: its own limits, the node's parameters (`param(name)`) for the rest."""
    from ..planning import PlannerConfig, TableBounds

    bounds = list(param("plan_table_bounds"))
    for name in ("max_speed", "time_budget", "mass", "position_tolerance", "yaw_tolerance"):
        v = float(getattr(req, name))
        if not np.isfinite(v) or v < 0:
            raise RequestError(f"{name} must be finite and >= 0 (0 = the node's default), got {v}")
    if 0 < req.position_tolerance < MIN_POSITION_TOLERANCE:
        raise RequestError(f"position_tolerance {req.position_tolerance:g} m is below {MIN_POSITION_TOLERANCE:g} "
                           "m: no push ends that exactly")
    if 0 < req.yaw_tolerance < MIN_YAW_TOLERANCE:
        raise RequestError(f"yaw_tolerance {req.yaw_tolerance:g} rad is below {MIN_YAW_TOLERANCE:g} rad: no push "
                           "ends that exactly")
    vmax = float(param("max_linear_speed"))
    max_speed = req.max_speed or float(param("plan_max_speed"))
    if max_speed > vmax:
        raise RequestError(f"max_speed {max_speed:g} m/s exceeds the node's max_linear_speed {vmax:g} m/s")
    if req.time_budget > MAX_TIME_BUDGET:
        raise RequestError(f"time_budget {req.time_budget:g} s exceeds {MAX_TIME_BUDGET:g} s")
    return PlannerConfig(max_speed=max_speed,
                         time_budget=req.time_budget or float(param("plan_time_budget")),
                         max_topple_probability=float(param("plan_max_topple_probability")),
                         density=float(param("plan_density")) or DEFAULT_DENSITY,
                         min_contact_height=float(param("plan_min_contact_height")),
                         max_contact_height=float(param("plan_max_contact_height")),
                         physics_check=bool(param("plan_physics_check")),
                         whole_cloud=bool(param("plan_whole_cloud")),
                         physics_fusion=bool(param("plan_physics_fusion")),
                         table=TableBounds(*bounds) if bounds else None)


def goal_of(req: PlanPush.Request, param: Callable[[str], Any]):
    """The request's Goal: its pose, its tolerances or the node's defaults."""
    from ..planning import Goal, Pose2D, yaw_of

    try:
        gp, gq = pose_to_numpy(req.goal_pose, zero_is_identity=True)
    except ValueError as exc:
        raise RequestError(f"goal_pose: {exc}") from None
    return Goal(Pose2D(float(gp[0]), float(gp[1]), float(yaw_of(gq))),
                req.position_tolerance or float(param("plan_position_tolerance")),
                req.yaw_tolerance or float(param("plan_yaw_tolerance")))


def start_of(req: PlanPush.Request, latest: ObjectState | None, object_id: str):
    """(Pose2D, (position, quaternion)) of the start: the latest object_state or the request's start_pose."""
    from ..planning import Pose2D, yaw_of

    if req.start_from_object_state:
        if latest is None:
            raise RequestError(f"start_from_object_state: no object_state of '{object_id}' received")
        pose_msg = latest.pose
    else:
        pose_msg = req.start_pose
    try:
        p, q = pose_to_numpy(pose_msg, zero_is_identity=True)
    except ValueError as exc:
        raise RequestError(f"start pose: {exc}") from None
    return Pose2D(float(p[0]), float(p[1]), float(yaw_of(q))), (p, q)


def fill_response(res: PlanPush.Response, plan: Any, frame: str, stamp: Any, object_id: str, model_id: str
                  ) -> PlanPush.Response:
    """A successful response from a PushPlan (table frame, the request's stamp)."""
    res.success, res.message = True, plan.message
    res.push_twist.linear.x, res.push_twist.linear.y, res.push_twist.linear.z = map(float, plan.lin_vel)
    res.push_twist.angular.x, res.push_twist.angular.y, res.push_twist.angular.z = map(float, plan.ang_vel)
    res.impulse.x, res.impulse.y, res.impulse.z = map(float, plan.impulse)
    res.contact_point.x, res.contact_point.y, res.contact_point.z = map(float, plan.contact_point)
    res.mass = float(plan.mass)
    res.predicted_final_pose = pose(plan.final_position, yaw_quaternion(plan.final_pose.yaw))
    res.predicted_position_error = float(plan.position_error)
    res.predicted_yaw_error = float(plan.yaw_error)
    res.within_tolerance = bool(plan.within_tolerance)
    res.success_probability = float(plan.success_probability)
    res.planning_time = float(plan.planning_time)
    res.trajectory = trajectory_to_msg(plan.trajectory, frame, stamp, object_id, model_id)
    # the plan's risk: the model's, the tipping estimate's, the robustness check's mean and the physics check's
    res.topple_probability = float(max(res.trajectory.topple_probability, plan.topple_probability,
                                       plan.robust_topple_probability, plan.physics_topple_probability))
    res.physics_topple_probability = float(plan.physics_topple_probability)
    res.spread = float(plan.spread)
    return res


def answer(node: Any, req: PlanPush.Request, res: PlanPush.Response) -> PlanPush.Response:
    """The plan_push callback of a PredictorNode: plan, or refuse with the reason (never raises)."""
    param = node._param
    try:
        node.check_frame(req.header.frame_id, "request header")
        cfg = planner_config(req, param)
        res.reach = float(cfg.reach())  # a refusal carries it too: push_to_goal splits a far goal by it
        goal = goal_of(req, param)
        object_id, cloud, shape = node.request_shape(req, None)
        latest = node.latest_state(object_id)
        if req.start_from_object_state and latest is not None:
            node.check_frame(latest.header.frame_id, "object_state")
        start, start_pose = start_of(req, latest, object_id)
        if cloud is None:  # the features' own points, when perception sent them: contacts on the surface
            node.select_feature(object_id, None)  # the newest must be usable (model, frame, width)
            cloud = node.rest_cloud(object_id, start_pose)
        if req.mass > 0:
            check_mass(req.mass, cloud if cloud is not None else shape)
        plan = node.planner.plan(shape if shape is not None else cloud, start, goal, cloud=cloud,
                                 mass=req.mass or None, config=cfg)
    except Exception as exc:  # noqa: BLE001 - answer with the reason, never crash on a request
        return node.refuse("plan_push", res, exc)
    stamp = req.header.stamp if time_to_ns(req.header.stamp) > 0 else node.get_clock().now().to_msg()
    fill_response(res, plan, node.table_frame, stamp, object_id, node.model_id)
    node.get_logger().info(f"plan_push '{object_id}': {plan.message}")
    return res
