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
"""Pusher: the `push_to_goal` action, closed-loop pushing on top of the predictor's plan_push.

For each goal (physdyn_ros/action/PushToGoal):
1. plan: the predictor's `plan_push` (start = the state this node saw the object rest in, with the points of the
   shape feature it waited for after that rest; goal = the session's aim: the goal, corrected by the observed /
   predicted slide ratio of the pushes so far; planning.session);
2. push: the sim node's `push_object` executes the impulse at the contact point, or, with execute_externally,
   a robot stack reads the planned push from the feedback (stage "pushing") and executes it itself;
3. observe: the object's states on `object_state` (state_source perception: `tracked_state`) until it rests
   (conventions.REST_*); after `steps_in` moving states the predictor re-predicts the rest pose from them
   (`predict_trajectory`'s observed states), sent as feedback;
4. stop (planning.session.PushSession, the same rules as the pybullet bench): reached, toppled, refused,
   out_of_pushes; also cancelled (checked before every push), invalid (a bad goal) and timeout (no state of
   the object, or a robot's push not seen to start, within its timeout; the object did not come to rest in
   time). A push the sim executed that is not seen to move the object within motion_timeout, while states of
   it at rest keep arriving, counts as a push that left it there (diagnostics: pushes_unseen).

A thin adapter: the episode's rules live in planning.session, the planning in the predictor (which holds the
model and the shape features), the physics in the sim node or the real world. No model is loaded here.
Goals run one at a time (a second goal is rejected while one runs: one pusher, one object moving).
A managed node like the others (ros/lifecycle.py): the action server exists from configure to cleanup and
accepts goals only while active; the subscriptions run while active; a goal running when the node is
deactivated stops before its next push with the reason.
"""
from __future__ import annotations

import math
import sys
import threading
import time
from collections import deque
from typing import Any, Optional

import numpy as np
from rclpy.action import CancelResponse, GoalResponse
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup

from ..action import PushToGoal
from ..conventions import REST_ANG_VEL, REST_FRAMES, REST_LIN_VEL, TABLE_FRAME
from ..msg import ObjectState, ShapeFeature
from ..planning.planner import Goal, PlanningError, Pose2D
from ..planning.session import PushSession, Stop, goal_errors
from ..ros.cloud import cloud_to_xyz
from ..ros.convert import pose, pose_to_numpy, quat_yaw, time_to_ns, twist_to_numpy, yaw_quaternion
from ..ros.diagnostics import OK, WARN, Diagnostics, Report
from ..ros.lifecycle import ManagedNode
from ..ros.params import declare
from ..ros.qos import reliable_client
from ..ros.run import run_node
from ..srv import PlanPush, PredictTrajectory, PushObject
from .predictor_node import FEATURE_QOS, STATE_QOS, STATE_SOURCES  # the subscriber side of the same topics



class EpisodeError(Exception):
    """Ends a goal early with an outcome (invalid, timeout, refused) and the reason."""

    def __init__(self, outcome: str, message: str) -> None:
        super().__init__(message)
        self.outcome = outcome


#: Pushes per goal at most (a goal's max_pushes is a uint32).
MAX_PUSHES = 50
#: s between checks, while a service call is pending, whether the node was deactivated
CALL_POLL = 0.05


def pose2d(msg) -> Pose2D:
    p, q = pose_to_numpy(msg, zero_is_identity=True)
    return Pose2D(float(p[0]), float(p[1]), float(quat_yaw(q)))


def moving(state: ObjectState) -> bool:
    lin, ang = twist_to_numpy(state.twist)
    return bool(np.linalg.norm(lin) >= REST_LIN_VEL or np.linalg.norm(ang) >= REST_ANG_VEL)


class PusherNode(ManagedNode):
    def __init__(self, **kwargs) -> None:
        super().__init__("pusher", **kwargs)
        self.table_frame = declare(self, "table_frame", TABLE_FRAME, "fixed frame of goals and object states",
                                   read_only=True)
        declare(self, "position_tolerance", 0.02, "m, default position tolerance of a goal", low=1e-4)
        declare(self, "yaw_tolerance", 0.1745, "rad, default yaw tolerance (>= pi: any yaw)", low=1e-4)
        declare(self, "max_pushes", 3, "default pushes per goal", low=1, high=MAX_PUSHES)
        declare(self, "adapt", True, "aim each push by the observed / predicted slide ratio of the pushes before")
        declare(self, "steps_in", 3, "observed states fed to the model to re-predict the rest pose (0 = off)",
                low=0, high=30)
        declare(self, "motion_timeout", 5.0, "s for a push the sim executed to be seen moving the object (seen "
                "resting instead: a push that left it there)", low=0.1)
        declare(self, "external_motion_timeout", 60.0, "s for a robot to execute a push (execute_externally)",
                low=0.1)
        declare(self, "rest_timeout", 15.0, "s for the pushed object to come to rest", low=0.1)
        declare(self, "feature_timeout", 5.0, "s for a shape feature of the object at rest after a push", low=0.1)
        declare(self, "service_timeout", 10.0, "s to wait for the predictor's and the sim's services (a plan or "
                "prediction not answered within it is asked once more; a push is waited for 30 s longer)", low=0.1)
        declare(self, "plan_service", "plan_push", "the predictor's PlanPush service", read_only=True)
        declare(self, "predict_service", "predict_trajectory", "the predictor's PredictTrajectory service",
                read_only=True)
        declare(self, "push_service", "push", "the sim node's PushObject service", read_only=True)
        declare(self, "state_source", "sim", "where the object's poses come from: 'sim' object_state (the sim or a "
                "tracker), 'perception' the perception node's tracked_state; the sim is then pushed at the contact "
                "point without an id (read on activate)", choices=STATE_SOURCES)

        self._states: dict[str, deque[ObjectState]] = {}  # the newest states per object
        self._received: dict[str, int] = {}  # states received per object in all (the deque drops the oldest)
        self._feature_ns: dict[str, int] = {}  # stamp of the newest shape feature per object
        self._points: dict[str, Any] = {}  # the newest feature's points (PointCloud2) per object
        self._perception = False  # state_source perception, as read on activate
        self._cond = threading.Condition()
        self._busy = threading.Lock()  # held by the running goal
        self._reserved = False  # a goal was accepted and has not finished (set under _cond)
        self._stopping = False  # deactivate / cleanup: running waits end at once
        self._session: Optional[PushSession] = None  # the running goal's, for a result after an early stop
        self._pose: Optional[Pose2D] = None
        self.counts = {k: 0 for k in ("goals", "reached", "refused", "toppled", "out_of_pushes", "cancelled",
                                      "invalid", "timeout", "pushes", "pushes_unseen")}
        self.last_result = ""
        # clients hold no resources: made once, used while active
        clients = ReentrantCallbackGroup()
        self.plan_client = reliable_client(self, PlanPush, self.get_parameter("plan_service").value,
                                           callback_group=clients)
        self.predict_client = reliable_client(self, PredictTrajectory, self.get_parameter("predict_service").value,
                                              callback_group=clients)
        self.push_client = reliable_client(self, PushObject, self.get_parameter("push_service").value,
                                           callback_group=clients)
        self._inputs = MutuallyExclusiveCallbackGroup()
        self.diagnostics = Diagnostics(self, "push_to_goal", self.report)
        self.start()  # autostart: configure + activate

    # ------------------------------------------------------------------------------------------ lifecycle
    def configure(self) -> None:
        self.configured_action_server(PushToGoal, "push_to_goal", self._execute, goal_callback=self._on_goal,
                                      cancel_callback=lambda _: CancelResponse.ACCEPT,
                                      callback_group=ReentrantCallbackGroup())

    def activate(self) -> None:
        self._stopping = False
        self._perception = self._param("state_source") == "perception"  # read once: the subscription matches it
        topic = "tracked_state" if self._perception else "object_state"
        self.active_subscription(ObjectState, topic, self._on_state, STATE_QOS, callback_group=self._inputs)
        self.active_subscription(ShapeFeature, "shape_feature", self._on_feature, FEATURE_QOS,
                                 callback_group=self._inputs)

    def deactivate(self) -> None:
        self._stop_goal()

    def _stop_goal(self) -> None:
        """A running goal stops at its next wait or push with the reason (no DDS input arrives any more)."""
        with self._cond:
            self._stopping = True
            self._cond.notify_all()

    def cleanup(self) -> None:
        self._stop_goal()
        if self._busy.acquire(timeout=5.0):  # the goal ends before its action server is destroyed
            self._busy.release()
        with self._cond:
            self._states.clear()
            self._received.clear()
            self._feature_ns.clear()

    def describe(self) -> str:
        return (f"action push_to_goal, plans from '{self.plan_client.srv_name}', pushes through "
                f"'{self.push_client.srv_name}'")

    # ------------------------------------------------------------------------------------------ inputs
    def _on_state(self, msg: ObjectState) -> None:
        with self._cond:
            self._states.setdefault(msg.object_id, deque(maxlen=600)).append(msg)
            self._received[msg.object_id] = self._received.get(msg.object_id, 0) + 1
            self._cond.notify_all()

    def _on_feature(self, msg: ShapeFeature) -> None:
        with self._cond:
            self._feature_ns[msg.object_id] = max(self._feature_ns.get(msg.object_id, 0),
                                                  time_to_ns(msg.header.stamp))
            self._points[msg.object_id] = msg.points
            self._cond.notify_all()

    def _cloud(self, object_id: str) -> Optional[np.ndarray]:
        """The latest feature's points of the object (table frame), None when none came with points."""
        with self._cond:
            msg = self._points.get(object_id)
        pts = cloud_to_xyz(msg) if msg is not None and msg.width * msg.height else None
        return pts if pts is not None and len(pts) >= 4 else None

    def _wait_feature(self, object_id: str, after_ns: int, push_index: int) -> None:
        """Wait for a shape feature of the object seen at or after after_ns (the object at rest): the next plan
        pushes on the surface where it lies now."""
        timeout = float(self._param("feature_timeout"))
        with self._cond:
            if not self._cond.wait_for(lambda: self._stopping or self._feature_ns.get(object_id, 0) >= after_ns,
                                       timeout):
                raise EpisodeError("timeout", f"push {push_index}: no shape feature of '{object_id}' at rest "
                                              f"within {timeout:g} s (is the perception node running?)")

    def report(self) -> Report:
        level = WARN if self.last_result.startswith(("invalid", "timeout")) else OK
        return level, self.last_result or "no goal yet", dict(self.counts)

    def _on_goal(self, _goal) -> GoalResponse:
        with self._cond:  # reserved here, released when _execute ends: two goals sent at once get one accept
            if self._reserved:
                self.get_logger().warning("push_to_goal: goal rejected: a goal is already running")
                return GoalResponse.REJECT
            self._reserved = True
        return GoalResponse.ACCEPT

    def _check_serving(self) -> None:
        if self._stopping or not self.is_active:
            raise EpisodeError("invalid", f"stopped: {self.not_serving()}")

    def _param(self, name: str):
        return self.get_parameter(name).value

    def _call(self, client, request, what: str, idempotent: bool = True):
        """The service's answer to `request`. A request that may run twice (a plan, a prediction; not a push) is
        sent again once when no answer came within service_timeout: a reply DDS dropped (one sent before the
        client's reply reader was matched) would otherwise hold the goal for the whole wait. Deactivating the node
        ends the wait at once."""
        timeout = float(self._param("service_timeout"))
        if not client.wait_for_service(timeout_sec=timeout):
            raise EpisodeError("invalid", f"{what} service '{client.srv_name}' is not available")
        waits = [timeout, timeout + 30.0] if idempotent else [timeout + 30.0]
        for attempt, wait in enumerate(waits):
            future = client.call_async(request)
            done = threading.Event()
            future.add_done_callback(lambda _f: done.set())
            deadline = time.monotonic() + wait
            while not done.wait(CALL_POLL) and time.monotonic() < deadline:
                if self._stopping or not self.is_active:
                    client.remove_pending_request(future)
                    raise EpisodeError("invalid", f"stopped: {self.not_serving()}")
            if done.is_set():
                return future.result()
            client.remove_pending_request(future)
            if attempt < len(waits) - 1:
                self.get_logger().warning(f"{what}: no answer within {wait:g} s; sending the request again")
        raise EpisodeError("timeout", f"{what} service '{client.srv_name}' did not answer")

    # ------------------------------------------------------------------------------------------- goal
    def _execute(self, handle) -> PushToGoal.Result:
        try:
            return self._run_goal(handle)
        finally:
            with self._cond:
                self._reserved = False

    def _run_goal(self, handle) -> PushToGoal.Result:
        with self._busy:
            self._session, self._pose = None, None
            self.counts["goals"] += 1
            result = PushToGoal.Result()
            try:
                stop, session, pose = self._episode(handle)
            except EpisodeError as exc:
                stop, session, pose = Stop(exc.outcome, str(exc)), self._session, self._pose
            except Exception as exc:  # noqa: BLE001 - a goal ends with the reason, the node keeps serving
                self.get_logger().error(f"push_to_goal: internal error: {type(exc).__name__}: {exc}")
                stop = Stop("invalid", f"internal error: {type(exc).__name__}: {exc}")
                session, pose = self._session, self._pose
            result.success, result.outcome, result.message = stop.success, stop.outcome, stop.message
            result.pushes = len(session.steps) if session else 0
            if pose is not None and session is not None:
                result.final_pose = pose_msg(pose, self._last_z(handle.request.object_id))
                result.position_error, result.yaw_error = goal_errors(pose, session.goal)
            self.counts[stop.outcome] = self.counts.get(stop.outcome, 0) + 1
            self.last_result = f"{stop.outcome}: {stop.message}"
            self.get_logger().info(f"push_to_goal '{handle.request.object_id}': {self.last_result}")
            if stop.outcome == "cancelled":
                handle.canceled()
            elif stop.success:
                handle.succeed()
            else:
                handle.abort()
            return result

    def _goal(self, req) -> Goal:
        if req.header.frame_id not in ("", self.table_frame):
            raise EpisodeError("invalid", f"goal frame '{req.header.frame_id}' is not the table frame "
                                          f"'{self.table_frame}'")
        for name in ("position_tolerance", "yaw_tolerance", "mass", "max_speed"):
            v = float(getattr(req, name))
            if not math.isfinite(v) or v < 0:
                raise EpisodeError("invalid", f"{name} must be finite and >= 0 (0 = the default), got {v}")
        try:
            return Goal(pose2d(req.goal_pose), req.position_tolerance or float(self._param("position_tolerance")),
                        req.yaw_tolerance or float(self._param("yaw_tolerance")))
        except (ValueError, PlanningError) as exc:
            raise EpisodeError("invalid", f"goal_pose: {exc}") from None

    @staticmethod
    def _state_pose(state: ObjectState) -> Pose2D:
        try:
            return pose2d(state.pose)
        except ValueError as exc:  # PlanningError / a non-finite pose from the tracker
            raise EpisodeError("invalid", f"object_state of '{state.object_id}': {exc}") from None

    def _latest(self, object_id: str) -> Optional[ObjectState]:
        with self._cond:
            states = self._states.get(object_id)
            return states[-1] if states else None

    def _last_z(self, object_id: str) -> float:
        s = self._latest(object_id)
        return float(s.pose.position.z) if s is not None else 0.0

    def _episode(self, handle) -> tuple[Stop, PushSession, Optional[Pose2D]]:
        req = handle.request
        goal = self._goal(req)
        max_pushes = int(req.max_pushes or self._param("max_pushes"))
        if max_pushes > MAX_PUSHES:
            raise EpisodeError("invalid", f"max_pushes {max_pushes} exceeds {MAX_PUSHES}")
        session = PushSession(goal, max_pushes, adapt=bool(self._param("adapt")))
        self._session, self._pose = session, None
        if not req.object_id:
            raise EpisodeError("invalid", "object_id is empty: name the object to push (its object_state id)")
        state = self._latest(req.object_id)
        if state is None:
            raise EpisodeError("invalid", f"no object_state of '{req.object_id}' received yet")
        reach = math.inf  # m one push slides: unknown until plan_push says
        # the yaw the object can show (an upright cylinder's is ignored): the stops fold it as the planner does
        session.observe_shape(self._cloud(req.object_id))
        goal = session.goal
        while True:
            pose = self._pose = self._state_pose(state)
            stop = session.check(pose, bool(state.toppled))
            if stop is not None:
                return stop, session, pose
            if handle.is_cancel_requested:
                return Stop("cancelled", f"cancelled before push {len(session.steps) + 1}"), session, pose
            self._check_serving()
            k = len(session.steps) + 1
            feedback = PushToGoal.Feedback(push_index=k, stage="planning")
            feedback.position_error, feedback.yaw_error = goal_errors(pose, goal)
            handle.publish_feedback(feedback)
            aim = session.aim(pose, reach=reach)
            plan = self._plan(req, aim, state)
            if not plan.success and 0 < plan.reach < reach:  # too far for one push: aim at the first leg's end
                reach = plan.reach
                aim = session.aim(pose, reach=reach)
                plan = self._plan(req, aim, state)
            if not plan.success and aim is not goal:  # the slide-ratio correction must not cause a refusal
                plan = self._plan(req, goal, state)
            if handle.is_cancel_requested:
                return Stop("cancelled", f"cancelled before push {k}"), session, pose
            if not plan.success:
                return session.refused(plan.message), session, pose
            if not any((plan.impulse.x, plan.impulse.y, plan.impulse.z)):  # "no push needed" for another pose
                return session.refused(f"the planner needs no push ({plan.message}) although the object is "
                                       f"{100 * goal_errors(pose, goal)[0]:.1f} cm from the goal"), session, pose
            feedback.stage, feedback.push_twist, feedback.impulse = "pushing", plan.push_twist, plan.impulse
            feedback.contact_point, feedback.topple_probability = plan.contact_point, plan.topple_probability
            feedback.success_probability = plan.success_probability
            feedback.predicted_rest_pose = plan.predicted_final_pose
            handle.publish_feedback(feedback)
            mark = self._mark(req.object_id)
            if not req.execute_externally:
                self._push(req.object_id, plan)
            state = self._observe(req, plan, state, mark, feedback, handle)
            rest = self._state_pose(state)
            session.record(pose, pose2d(plan.predicted_final_pose), rest, bool(state.toppled))
            self.counts["pushes"] += 1
            if session.check(rest, bool(state.toppled)) is None:  # another push follows: see where it lies
                self._wait_feature(req.object_id, time_to_ns(state.header.stamp), k)
            feedback.stage, feedback.observed_rest_pose = "rested", state.pose
            feedback.position_error, feedback.yaw_error = goal_errors(rest, goal)
            handle.publish_feedback(feedback)

    def _plan(self, req, aim: Goal, start: ObjectState) -> PlanPush.Response:
        """plan_push from `start`, the state this node saw the object rest in: not the predictor's latest
        object_state, which may still be a moving one its executor has not replaced yet (a plan for where the
        object was a frame ago puts the contact centimetres off its surface)."""
        plan_req = PlanPush.Request(object_id=req.object_id, start_from_object_state=False, start_pose=start.pose,
                                    mass=req.mass, max_speed=req.max_speed,
                                    position_tolerance=aim.position_tolerance, yaw_tolerance=aim.yaw_tolerance)
        plan_req.header.frame_id = self.table_frame
        plan_req.goal_pose = pose_msg(aim.pose, float(start.pose.position.z))
        with self._cond:  # the cloud of the feature this node waited for, seen at rest where `start` is: the
            points = self._points.get(req.object_id)  # predictor may not have received it yet
        if points is not None and points.width * points.height >= 4:
            plan_req.cloud = points
        return self._call(self.plan_client, plan_req, "plan_push")

    def _push(self, object_id: str, plan: PlanPush.Response) -> None:
        # perception's track ids are not the sim's: the sim pushes the object at the contact point
        sim_id = "" if self._perception else object_id
        res = self._call(self.push_client, PushObject.Request(object_id=sim_id, impulse=plan.impulse,
                                                              point=plan.contact_point), "push_object",
                         idempotent=False)
        if not res.success:
            raise EpisodeError("invalid", f"push_object refused the push: {res.message}")

    # ---------------------------------------------------------------------------------------- observing
    def _mark(self, object_id: str) -> int:
        """A position in the object's state history: the states after it arrived after this call."""
        with self._cond:
            return self._received.get(object_id, 0)

    def _since(self, object_id: str, mark: int) -> tuple[list[ObjectState], int]:
        """States of object_id received after `mark` (call with the condition held), and the new mark."""
        states = self._states.get(object_id, deque())
        total = self._received.get(object_id, 0)
        return list(states)[max(0, mark - (total - len(states))):], total

    def _observe(self, req, plan: PlanPush.Response, start: ObjectState, mark: int, feedback, handle
                 ) -> ObjectState:
        """Wait for the push to move the object, then for it to rest; the rest state. Re-predicts after
        steps_in moving states."""
        object_id = req.object_id
        motion_timeout = float(self._param("external_motion_timeout" if req.execute_externally else
                                           "motion_timeout"))
        steps_in = int(self._param("steps_in"))
        feedback.stage = "observing"
        moved: list[ObjectState] = []
        # the resting states seen since the push: how many, the latest and when it arrived
        still: Optional[ObjectState] = None
        still_count, still_at = 0, 0.0
        quiet, limit = 0, motion_timeout
        deadline = time.monotonic() + limit
        while True:
            with self._cond:
                new, mark = self._since(object_id, mark)
                if self._stopping:
                    raise EpisodeError("invalid", f"stopped during push {feedback.push_index}: "
                                                  f"{self.not_serving()}")
                if not new:
                    # a robot that has not pushed yet: stop waiting (a push the sim executed finishes first)
                    if not moved and req.execute_externally and handle.is_cancel_requested:
                        raise EpisodeError("cancelled", f"cancelled before push {feedback.push_index} moved "
                                                        "the object")
                    left = deadline - time.monotonic()
                    if left <= 0:
                        seen_resting = (still is not None and still_count >= REST_FRAMES
                                        and time.monotonic() - still_at < 0.5 * limit)
                        if not moved and seen_resting and not req.execute_externally:
                            # the push was executed and the object is still seen, resting: too weak a push (a
                            # mass read low from one side of the object) moved it less than the camera shows;
                            # the session goes on from there and aims the next one farther
                            self.counts["pushes_unseen"] += 1
                            self.get_logger().warning(
                                f"push_to_goal '{object_id}': push {feedback.push_index}: no motion seen within "
                                f"{limit:g} s; the object rests where it was seen")
                            return still
                        what = "come to rest" if moved else "start moving"
                        seen = "" if moved or req.execute_externally else " (nor seen resting since the push)"
                        raise EpisodeError("timeout", f"push {feedback.push_index}: the object did not {what} "
                                                      f"within {limit:g} s{seen}")
                    self._cond.wait(min(left, 0.5))
                    continue
            for s in new:
                if not moved:
                    if not moving(s):
                        still, still_count, still_at = s, still_count + 1, time.monotonic()
                        continue
                    limit = float(self._param("rest_timeout"))
                    deadline = time.monotonic() + limit
                moved.append(s)
                quiet = 0 if moving(s) else quiet + 1
                if len(moved) == steps_in + 1 and steps_in > 0:
                    self._repredict(req, plan, start, moved, feedback, handle)
                if quiet >= REST_FRAMES or (s.toppled and quiet >= 1):
                    return s

    def _repredict(self, req, plan: PlanPush.Response, start: ObjectState, moved: list[ObjectState], feedback,
                   handle) -> None:
        """Feed the observed states after the push's first (frame 0) to the model: a better rest prediction."""
        pred = PredictTrajectory.Request(object_id=req.object_id, initial_pose=moved[0].pose,
                                         initial_twist=moved[0].twist, observed=moved[1:])
        pred.header.frame_id = self.table_frame
        try:
            res = self._call(self.predict_client, pred, "predict_trajectory")
        except EpisodeError as exc:
            self.get_logger().warning(f"push_to_goal: no re-prediction: {exc}")
            return
        if res.success and res.trajectory.states:
            feedback.predicted_rest_pose = res.trajectory.states[-1].pose
            feedback.steps_in = len(moved) - 1
            handle.publish_feedback(feedback)


def pose_msg(p: Pose2D, z: float):
    return pose([p.x, p.y, z], yaw_quaternion(p.yaw))


def main(args: list[str] | None = None) -> int:
    return run_node(PusherNode, "pusher", args, threads=4)


if __name__ == "__main__":
    sys.exit(main())
