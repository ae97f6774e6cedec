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
"""Predictor: shape feature + the velocities right after a push -> the predicted trajectory of the object.

Inputs
  shape_feature   (ShapeFeature)   from the perception node; the last few per object are kept
  initial_twist   (TwistStamped)   velocities right after a push, table frame; each one triggers a prediction
  object_state    (ObjectState)    the object's pose over time (tracker or sim): gives the pose at the push
  observed_state  (ObjectState)    observed states after the push: steps_in > 0 refines the prediction with them
  state_source perception instead: initial_state (ObjectState, the perception node's push onsets: each one
  triggers a prediction for its object) and tracked_state (ObjectState: poses and observed states)
Outputs (reliable, transient local, depth 1: the latest prediction reaches late joiners)
  predicted_trajectory (PredictedTrajectory), predicted_path (nav_msgs/Path), predicted_markers (MarkerArray)
Services
  predict_trajectory (PredictTrajectory): a one-off roll-out for a cloud or a known object_id.
  plan_push (PlanPush): the push that brings an object to a goal pose (physdyn_ros.planning, ros/plan_push.py).

A managed (lifecycle) node, see physdyn_ros/ros/lifecycle.py: the model and the planner are loaded on configure
and released on cleanup; publishers, services and the refinement timer exist from configure to cleanup,
subscriptions from activate to deactivate; the services answer only while active (otherwise success=false,
"node is inactive (lifecycle state ...)"). With `autostart` (default) the node configures and activates itself at
start, and a checkpoint that cannot be loaded stops the executable with a non-zero exit; with autostart false a
failed configure leaves it unconfigured and alive, with the reason logged and on /diagnostics.
Everything runs on one SingleThreadedExecutor: under a MultiThreadedExecutor the callbacks contended for the GIL
(each took twice as long) and twists queued ~100 ms behind them (ros2/rclpy#1452). Nothing blocks: a twist
whose object_state of the push instant has not arrived yet is parked until that state arrives or `state_wait`
passes; DDS queues (states: depth 200) hold the data that arrives while a roll-out or a plan runs.
"""
from __future__ import annotations

import sys
import threading
import time
from collections import deque

import numpy as np
from geometry_msgs.msg import TwistStamped
from nav_msgs.msg import Path
from visualization_msgs.msg import MarkerArray

from ..conventions import REST_ANG_VEL, REST_LIN_VEL, TABLE_FRAME
from ..msg import ObjectState, PredictedTrajectory, ShapeFeature
from ..ros.cloud import cloud_to_xyz
from ..ros.convert import pose_to_numpy, time_to_ns, twist_to_numpy, xyz_to_numpy, yaw_quaternion
from ..ros.diagnostics import OK, Diagnostics, RefusalWindow, Report
from ..ros.lifecycle import ManagedNode
from ..ros.model import load_ensemble, load_predictor
from ..ros import plan_push
from ..ros.params import declare
from ..ros.pending import ParkedTwist, PendingRefinement, refine
from ..ros.requests import (MAX_DENSITY, RequestError, check_feature, check_feature_age, check_pose_on_cloud,
                             observed_steps, ordered_bounds, shape_code)
from ..ros.qos import FEATURE_QOS, LATCHED, STATE_QOS
from ..ros.run import run_node
from ..ros.throttle import ReasonThrottle
from ..ros.trajectory import msg_to_path, trajectory_markers, trajectory_to_msg
from ..shapes.core import DEFAULT_DENSITY
from ..srv import PlanPush, PredictTrajectory

#: Where the pose at the push comes from (parameter initial_pose_source).
POSE_SOURCES = ("object_state", "shape_feature")
#: Where poses and pushes come from (parameter state_source): the sim's (or a tracker's) object_state and
#: initial_twist, or the perception node's tracked_state and initial_state.
STATE_SOURCES = ("sim", "perception")
#: A stamp this close to another counts as the same instant (float round-trips of stamps).
SAME_INSTANT_NS = 1_000_000
NS = 1e-9
#: Stamps further apart than this (s) are not of one session: one is unset or from another clock.
ABSURD_GAP = 86_400.0
#: m/s: the largest vertical speed of the training pushes (3.5 m/s at 10 degrees above the horizontal).
MAX_VERTICAL_SPEED = 0.6


class PredictorNode(ManagedNode):
    """Publishes a predicted trajectory for every initial_twist, and answers predict_trajectory."""

    def __init__(self, **kwargs) -> None:
        super().__init__("predictor", **kwargs)
        declare(self, "model_path", "", "checkpoint, loaded on configure (cleanup, set, configure: another model); "
                "empty = the shipped default model")
        declare(self, "device", "cpu", "torch device (read on configure)")
        declare(self, "precision", "auto", "batched roll-outs (the planner's): auto = bf16 products where the CPU "
                "has bf16 arithmetic (read on configure)", choices=("auto", "fp32", "bf16"))
        declare(self, "num_threads", 1, "torch intra-op threads (set explicitly: no oversubscription; read on "
                "configure)", low=1, high=256)
        declare(self, "topple_fusion", False, "predict_trajectory requests with a whole cloud fuse the model's "
                "topple probability with pybullet on the cloud's solid (5 runs, 25-120 ms more; needs the "
                "checkpoint's .topple_fusion.json; read on configure)")
        declare(self, "topple_fusion_friction", 0.5, "nominal Coulomb friction of the topple fusion's physics (read "
                "on configure)", low=0.01, high=10.0)
        declare(self, "rest_spread", True, "each prediction also rolls out its push 10 % weaker and stronger for "
                "the trajectory's calibrated spread (rest_position_spread, ...; about 2 ms more); false: those "
                "fields are NaN")
        self.table_frame: str = declare(self, "table_frame", TABLE_FRAME, "fixed frame of every input and "
                                        "output; inputs in another frame are rejected (no tf lookup)",
                                        read_only=True)
        declare(self, "state_source", "sim", "'sim': predict for each initial_twist, poses from object_state, "
                "observed states from observed_state; 'perception': predict for each initial_state of the perception "
                "node (its object, pose and twist), refine with its tracked_state (read on activate)",
                choices=STATE_SOURCES)
        declare(self, "object_id", "", "predict for this object only; empty = the latest shape feature's object")
        declare(self, "horizon", 60, "steps predicted per push (1/15 s each) and the service default; at most "
                "the model's max_horizon", low=1, check=self._within_max_horizon)
        declare(self, "initial_pose_source", "object_state", "'object_state': pose at the push = the "
                "object_state stamped at the twist's stamp (waits up to state_wait for it); 'shape_feature': "
                "the feature's centroid and canonical heading (no tracker needed; predicted poses are then "
                "those of the cloud's canonical frame)", choices=POSE_SOURCES)
        declare(self, "max_feature_age", 5.0, "s: a shape feature this much older than the twist is stale (0: any)",
                low=0.0)
        declare(self, "max_state_age", 0.5, "the object_state used as initial pose must be within this many "
                "seconds of the twist's stamp", low=0.0)
        declare(self, "state_wait", 0.25, "s to wait for the object_state of the twist's stamp", low=0.0, high=10.0)
        declare(self, "max_linear_speed", 5.0, "initial |v| above this (m/s) is rejected", low=0.0)
        declare(self, "max_angular_speed", 60.0, "initial |w| above this (rad/s) is rejected", low=0.0)
        declare(self, "max_vertical_speed", MAX_VERTICAL_SPEED, "initial |v_z| above this (m/s) is rejected: the "
                "model was trained on pushes along the table (impulses at most 10 degrees off the horizontal), "
                "not on launches or objects driven into the table", low=0.0)
        declare(self, "steps_in", 0, "observed states (observed_state topic; state_source perception: "
                "tracked_state) after the push to feed the model "
                "before it predicts on its own; > 0 publishes a corrected trajectory for each observed state, up to "
                "steps_in", low=0)
        declare(self, "box_every", 10, "a CUBE marker every this many steps (and at the last)", low=1)
        declare(self, "plan_time_budget", 0.2, "s of planning per plan_push request (default of the request's "
                "time_budget)", low=0.01, high=30.0)
        declare(self, "plan_max_speed", 1.5, "m/s, fastest push plan_push may choose (request default)", low=0.01)
        declare(self, "plan_max_topple_probability", 0.35, "plan_push rejects pushes predicted to topple more "
                "likely than this", low=0.0, high=1.0)
        declare(self, "plan_physics_check", True, "plan_push re-simulates its finalists on the cloud's hull "
                "(pybullet) and keeps only pushes that stay upright there too (planning.physics_check)")
        declare(self, "plan_whole_cloud", True, "plan_push's clouds sample every side of the object (the sim's "
                "surface clouds): the physics check weighs the solid they enclose, not their convex hull "
                "(shapes.solid); false for one camera's view")
        declare(self, "plan_physics_fusion", True, "with whole clouds, the physics check's verdict is the model's "
                "topple fusion with the solid's runs, where the checkpoint has .topple_fusion.json weights "
                "(physdyn_ros.topple_fusion); false: the share of toppled runs vetoes")
        declare(self, "plan_ensemble", 0, "models in plan_push's robustness check (read on configure): n > 1 adds "
                "n - 1 members (plan_ensemble_models, else the shipped ones beside the shipped model), 1 = the model "
                "alone, 0 = every member named or shipped (none with another model and no plan_ensemble_models); a "
                "push's topple risk is the highest member's, its spread widened by their disagreement", low=0,
                high=16)
        declare(self, "plan_ensemble_models", [""], "checkpoints of the further ensemble members (read on "
                "configure); empty entries ignored; none: the shipped members (only with the shipped model)")
        declare(self, "plan_position_tolerance", 0.02, "m, default position tolerance of plan_push", low=1e-4)
        declare(self, "plan_yaw_tolerance", 0.1745, "rad, default yaw tolerance of plan_push (>= pi: any yaw)",
                low=1e-4)
        declare(self, "plan_min_contact_height", 0.005, "m above the table: lowest point a pusher can touch",
                low=0.0, high=2.0)
        declare(self, "plan_max_contact_height", 0.5, "m above the table: highest point a pusher can touch",
                low=0.001, high=2.0)
        declare(self, "plan_density", 0.0, "kg/m^3, for the mass estimate (hull volume x density) when a request "
                f"gives no mass; 0 = the simulator's density ({DEFAULT_DENSITY:g}, shapes.DEFAULT_DENSITY)",
                low=0.0, high=MAX_DENSITY)
        declare(self, "plan_table_bounds", [-1.0, 1.0, -1.0, 1.0], "x_min, x_max, y_min, y_max (m) of the table "
                "top in table_frame: starts, goals and predicted paths must stay inside", length=4,
                check=ordered_bounds)

        self.predictor = None  # the model (Predictor) and planner: loaded on configure, released on cleanup
        self.planner = None
        self.model_id: str = ""
        self._lock = threading.Condition()
        self._features: dict[str, deque[ShapeFeature]] = {}
        self._latest_feature_id: str | None = None
        self._states: dict[str, deque[ObjectState]] = {}
        self._observed: dict[str, deque[ObjectState]] = {}
        self._perception = False  # state_source perception, as read on activate
        self._pending: list[PendingRefinement] = []
        self._parked: list[ParkedTwist] = []
        self.predictions = 0
        self.rejected = 0
        self.last_error = ""
        self._error_log = ReasonThrottle(self.get_logger(), "error", 1.0)
        self._warn_log = ReasonThrottle(self.get_logger(), "warning", 1.0)

        # One group, the node's default one, which also runs the lifecycle transitions: the node runs on a single
        # thread (main()); the group only matters to a caller that adds this node to a MultiThreadedExecutor,
        # where roll-outs must still not run concurrently, nor a cleanup release the model under a roll-out.
        self._infer = self.default_callback_group
        self._data = self._infer
        self._latency_ms: deque[float] = deque(maxlen=100)
        self._refusals = RefusalWindow()
        self.diagnostics = Diagnostics(self, "predictions", self._diagnose, callback_group=self._infer)
        self.start()  # autostart: configure + activate

    # -------------------------------------------------------------------------------------------- lifecycle
    def configure(self) -> None:
        p = self._param
        predictor = load_predictor(self, p("model_path"), p("device"), int(p("num_threads")), p("precision"),
                                   bool(p("topple_fusion")), float(p("topple_fusion_friction")))
        if int(p("horizon")) > int(predictor.max_horizon):
            raise ValueError(f"parameter horizon {p('horizon')} exceeds the max_horizon {predictor.max_horizon} of "
                             f"model {predictor.model_id}")
        self.predictor = predictor
        self.model_id = self.predictor.model_id
        if bool(p("rest_spread")) and predictor.spread_calibration is None:
            self.get_logger().warning(f"rest_spread: {predictor.spread_problem}; predictions carry the topple "
                                      "spread only (rest_position_spread and rest_yaw_spread NaN)")
        from ..planning import PushPlanner

        members = load_ensemble(self, int(p("plan_ensemble")), list(p("plan_ensemble_models")), p("model_path"),
                                p("device"), int(p("num_threads")), p("precision"))
        self.planner = PushPlanner(self.predictor, ensemble=members)
        self.planner.warm_up()  # timing calibration and first-call costs, before the node serves
        self.pub_traj = self.configured_publisher(PredictedTrajectory, "predicted_trajectory", LATCHED)
        self.pub_path = self.configured_publisher(Path, "predicted_path", LATCHED)
        self.pub_markers = self.configured_publisher(MarkerArray, "predicted_markers", LATCHED)
        self.configured_service(PredictTrajectory, "predict_trajectory", self._on_service, callback_group=self._infer)
        self.configured_service(PlanPush, "plan_push", self._on_plan, callback_group=self._infer)
        self.configured_timer(0.05, self._on_refine_timer, callback_group=self._infer)

    def activate(self) -> None:
        self.active_subscription(ShapeFeature, "shape_feature", self._on_feature, FEATURE_QOS,
                                 callback_group=self._data)
        self._perception = self._param("state_source") == "perception"  # read once: the subscriptions match it
        if self._perception:  # the tracker's states alone: no ground truth is read
            self.active_subscription(ObjectState, "tracked_state", self._on_tracked, STATE_QOS,
                                     callback_group=self._data)
            self.active_subscription(ObjectState, "initial_state", self._on_initial_state, STATE_QOS,
                                     callback_group=self._infer)
            return
        self.active_subscription(ObjectState, "object_state", self._on_state, STATE_QOS, callback_group=self._data)
        self.active_subscription(ObjectState, "observed_state", self._on_observed, STATE_QOS,
                                 callback_group=self._data)
        self.active_subscription(TwistStamped, "initial_twist", self._on_twist, 10, callback_group=self._infer)

    def deactivate(self) -> None:
        with self._lock:  # pushes in flight are dropped: nothing is published while inactive
            self._parked.clear()
            self._pending.clear()

    def cleanup(self) -> None:
        with self._lock:
            self._features.clear()
            self._states.clear()
            self._observed.clear()
            self._latest_feature_id = None
            self._parked.clear()
            self._pending.clear()
        for holder in (self.planner, self.predictor):  # their pybullet clients (physics check, topple fusion)
            if holder is not None:
                holder.close()
        self.predictor = self.planner = None  # the model's tensors go with the last references
        self.model_id = ""
        import gc

        gc.collect()

    def describe(self) -> str:
        return f"model {self.model_id}, horizon {self._param('horizon')}, frame '{self.table_frame}'"

    def _diagnose(self) -> Report:
        level = self._refusals.level(self.rejected)
        lat = np.asarray(self._latency_ms) if self._latency_ms else np.zeros(1)
        message = f"last refusal: {self.last_error}" if level != OK else "predicting"
        return level, message, {
            "model_id": self.model_id, "model_loaded": self.predictor is not None,
            "predictions": self.predictions, "refusals": self.rejected,
            "last_refusal": self.last_error, "latency_p50_ms": f"{np.percentile(lat, 50):.2f}",
            "latency_max_ms": f"{lat.max():.2f}", "objects_with_features": len(self._features),
            "parked_twists": len(self._parked), "pending_refinements": len(self._pending)}

    # ---------------------------------------------------------------------------------------------- buffers
    def _on_feature(self, msg: ShapeFeature) -> None:
        with self._lock:
            self._features.setdefault(msg.object_id, deque(maxlen=16)).append(msg)
            self._latest_feature_id = msg.object_id
            self._lock.notify_all()

    def _on_state(self, msg: ObjectState) -> None:
        with self._lock:
            self._states.setdefault(msg.object_id, deque(maxlen=512)).append(msg)
            self._lock.notify_all()
        if self._parked:
            self._release_parked()

    def _on_observed(self, msg: ObjectState) -> None:
        with self._lock:
            self._observed.setdefault(msg.object_id, deque(maxlen=512)).append(msg)

    def _on_tracked(self, msg: ObjectState) -> None:
        """A tracked state is both the pose history (pushes start from it) and an observed step after a push."""
        self._on_state(msg)
        self._on_observed(msg)

    def _on_initial_state(self, msg: ObjectState) -> None:
        """A push the tracker saw begin: predict for its object from its pose and twist at the onset (only for
        the object_id parameter's object when that is set)."""
        t_start = time.monotonic()
        wanted = self._param("object_id")
        if wanted and msg.object_id != wanted:
            return
        try:
            self.check_frame(msg.header.frame_id, "initial_state")
            pose = pose_to_numpy(msg.pose)
        except ValueError as exc:
            self._fail(str(exc))
            return
        self._predict(msg.object_id, msg.header.stamp, msg.twist, t_start, pose, "initial_state")

    # ----------------------------------------------------------------------------------------------- checks
    def _param(self, name: str):
        return self.get_parameter(name).value

    def check_frame(self, frame_id: str, what: str) -> None:
        if frame_id != self.table_frame:
            raise RequestError(f"{what} frame_id '{frame_id}' is not the table frame '{self.table_frame}' "
                               "(this node does not use tf)")

    def check_velocity(self, lin: np.ndarray, ang: np.ndarray) -> None:
        if not (np.all(np.isfinite(lin)) and np.all(np.isfinite(ang))):
            raise RequestError(f"velocity is not finite: linear {lin.tolist()}, angular {ang.tolist()}")
        vmax, wmax = float(self._param("max_linear_speed")), float(self._param("max_angular_speed"))
        if np.linalg.norm(lin) > vmax:
            raise RequestError(f"linear speed {np.linalg.norm(lin):.3g} m/s exceeds max_linear_speed {vmax:g}")
        if np.linalg.norm(ang) > wmax:
            raise RequestError(f"angular speed {np.linalg.norm(ang):.3g} rad/s exceeds max_angular_speed {wmax:g}")
        vzmax = float(self._param("max_vertical_speed"))
        if abs(lin[2]) > vzmax:
            raise RequestError(f"vertical speed linear.z = {lin[2]:.3g} m/s exceeds max_vertical_speed {vzmax:g}: "
                               "the model predicts pushes along the table, not launches or objects driven into it")

    def _within_max_horizon(self, value: int) -> str | None:
        """Parameter check: horizon may not exceed the loaded model's max_horizon."""
        predictor = getattr(self, "predictor", None)
        if predictor is not None and int(value) > int(predictor.max_horizon):
            return f"{value} exceeds the max_horizon {predictor.max_horizon} of model {predictor.model_id}"
        return None

    def target_object(self, requested: str = "") -> str:
        oid = requested or self._param("object_id") or self._latest_feature_id
        if not oid:
            raise RequestError("no shape feature received yet (is the perception node running and does it see "
                               "the object?)")
        return oid

    def select_feature(self, object_id: str, t_ns: int | None) -> ShapeFeature:
        """The newest feature of object_id stamped at or before t (or the newest one when t is None); it must be
        fresh and come from this node's model."""
        with self._lock:
            feats = list(self._features.get(object_id, ()))
        if not feats:
            known = ", ".join(sorted(self._features)) or "none"
            raise RequestError(f"no shape feature received for object '{object_id}' (known objects: {known})")
        if t_ns is None:
            feat = feats[-1]
        else:
            before = [f for f in feats if time_to_ns(f.header.stamp) <= t_ns + SAME_INSTANT_NS]
            feat = before[-1] if before else feats[0]
            check_feature_age(object_id, time_to_ns(feat.header.stamp), t_ns, float(self._param("max_feature_age")))
        check_feature(feat, object_id, self.model_id, self.table_frame, int(self.predictor.feature_dim))
        return feat

    def feature_cloud(self, feat: ShapeFeature) -> np.ndarray | None:
        """The points a feature carries (ShapeFeature.points, table frame), or None when it has none."""
        if feat.points.width * feat.points.height == 0:
            return None
        self.check_frame(feat.points.header.frame_id or self.table_frame, "shape feature points")
        try:
            pts = cloud_to_xyz(feat.points, max_points=100_000, rng=np.random.default_rng(0))
        except ValueError as exc:
            raise RequestError(f"shape feature points: {exc}") from None
        return pts if len(pts) >= 4 else None

    def rest_cloud(self, object_id: str, pose: tuple[np.ndarray, np.ndarray]) -> np.ndarray | None:
        """The newest feature points of object_id whose pose when seen is known, moved to `pose` (a feature seen
        mid-push is skipped: this node may not have the one seen at rest yet). None when there are none."""
        with self._lock:
            feats = list(self._features.get(object_id, ()))
        for feat in reversed(feats):
            cloud = self.feature_cloud(feat)
            moved = None if cloud is None else self.repose(cloud, object_id, time_to_ns(feat.header.stamp), pose)
            if moved is not None:
                return moved
        return None

    def repose(self, points: np.ndarray, object_id: str, t_ns: int, pose: tuple[np.ndarray, np.ndarray]
               ) -> np.ndarray | None:
        """Points observed at t_ns moved with the object to `pose` (position, quaternion) from where its object_state
        says it was then; None when it was moving then (its pose at t_ns is unknown)."""
        from scipy.spatial.transform import Rotation

        then, exact = self.state_at(object_id, t_ns)
        if then is None:
            return points
        lin, ang = twist_to_numpy(then.twist)
        if not exact and (np.linalg.norm(lin) >= REST_LIN_VEL or np.linalg.norm(ang) >= REST_ANG_VEL):
            return None  # the object moved between that state and the cloud: its pose then is unknown
        p0, q0 = pose_to_numpy(then.pose, zero_is_identity=True)
        rot = Rotation.from_quat(pose[1]) * Rotation.from_quat(q0).inv()
        return rot.apply(points - p0) + pose[0]

    def shape_code(self, feat: ShapeFeature):
        return shape_code(feat)

    def state_at(self, object_id: str, t_ns: int) -> tuple[ObjectState | None, bool]:
        """The newest object_state at or before t_ns, and whether it is the state of that instant."""
        with self._lock:
            best = None
            for s in reversed(self._states.get(object_id, ())):
                if time_to_ns(s.header.stamp) <= t_ns + SAME_INSTANT_NS:
                    best = s
                    break
        return best, best is not None and time_to_ns(best.header.stamp) >= t_ns - SAME_INSTANT_NS

    def pose_at(self, object_id: str, t_ns: int, feat: ShapeFeature) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Initial (position, orientation) for a push at t_ns (None, None: the Predictor's defaults)."""
        source = self._param("initial_pose_source")
        if source == "shape_feature":
            h = float(feat.heading)
            return xyz_to_numpy(feat.centroid), yaw_quaternion(h)
        best, _ = self.state_at(object_id, t_ns)
        if best is None:
            raise RequestError(f"no object_state of '{object_id}' at or before the push (initial_pose_source "
                               "object_state needs a tracker or the sim on object_state)")
        gap = (t_ns - time_to_ns(best.header.stamp)) * NS
        if gap > float(self._param("max_state_age")):
            raise RequestError(f"latest object_state of '{object_id}' is {gap:.2f} s older than the push "
                               f"(max_state_age {self._param('max_state_age'):g} s)")
        self.check_frame(best.header.frame_id, "object_state")
        try:
            return pose_to_numpy(best.pose)
        except ValueError as exc:
            raise RequestError(f"object_state pose: {exc}") from None

    # ------------------------------------------------------------------------------------------ predictions
    def horizon(self, requested: int = 0) -> int:
        h = int(requested) or int(self._param("horizon"))
        if h > int(self.predictor.max_horizon):
            raise RequestError(f"horizon {h} exceeds the model's max_horizon {self.predictor.max_horizon}")
        return h

    def publish(self, traj: PredictedTrajectory, feat: ShapeFeature | None) -> None:
        self.pub_traj.publish(traj)
        self.pub_path.publish(msg_to_path(traj))
        extents = xyz_to_numpy(feat.half_extents) if feat is not None else None
        heading = float(feat.heading) if feat is not None else 0.0
        self.pub_markers.publish(trajectory_markers(traj, extents, heading, int(self._param("box_every"))))

    def _fail(self, reason: str) -> None:
        self.rejected += 1
        self.last_error = reason
        self._error_log(f"no prediction: {reason}", reason)

    def _on_twist(self, msg: TwistStamped) -> None:
        t_start = time.monotonic()
        if self._param("initial_pose_source") == "object_state" and float(self._param("state_wait")) > 0:
            # The state of the push instant may arrive just after the twist: park the twist until it does.
            oid = self._param("object_id") or self._latest_feature_id
            if oid and time_to_ns(msg.header.stamp) > 0 and not self.state_at(oid, time_to_ns(msg.header.stamp))[1]:
                self._parked.append(ParkedTwist(msg, t_start, t_start + float(self._param("state_wait"))))
                return
        self._predict_twist(msg, t_start)

    def _release_parked(self) -> None:
        """Predict the parked twists whose state arrived, and those whose wait is over (with the states there are)."""
        now, keep = time.monotonic(), []
        for p in self._parked:
            oid = self._param("object_id") or self._latest_feature_id
            ready = bool(oid) and self.state_at(oid, time_to_ns(p.msg.header.stamp))[1]
            if ready or now >= p.deadline:
                self._predict_twist(p.msg, p.t_start)
            else:
                keep.append(p)
        self._parked = keep

    def _predict_twist(self, msg: TwistStamped, t_start: float) -> None:
        try:
            self.check_frame(msg.header.frame_id, "initial_twist")
        except ValueError as exc:
            self._fail(str(exc))
            return
        self._predict("", msg.header.stamp, msg.twist, t_start, None)

    def _predict(self, object_id: str, stamp, twist, t_start: float, pose: tuple | None,
                 what: str = "initial_twist") -> None:
        """Predict and publish the push of `object_id` (empty: the target_object) at `stamp` with velocities
        `twist`, from `pose` (position, orientation), or where initial_pose_source says when None."""
        try:
            lin, ang = twist_to_numpy(twist)
            self.check_velocity(lin, ang)
            t_ns = time_to_ns(stamp)
            if t_ns <= 0:
                raise RequestError(f"{what} header.stamp is unset (0): stamp the {what[8:]} with the instant of "
                                   "the push (the node's clock, e.g. node.get_clock().now())")
            object_id = object_id or self.target_object()
            feat = self.select_feature(object_id, t_ns)
            position, orientation = pose if pose is not None else self.pose_at(object_id, t_ns, feat)
            traj = self.predictor.rollout(self.shape_code(feat), lin, ang, horizon=self.horizon(),
                                          position=position, orientation=orientation,
                                          spread=bool(self._param("rest_spread")))
        except ValueError as exc:  # RequestError, or the Predictor refusing an input
            self._fail(str(exc))
            return
        except Exception as exc:  # noqa: BLE001 - never let one bad message take the node down
            self._fail(f"internal error: {type(exc).__name__}: {exc}")
            return
        out = trajectory_to_msg(traj, self.table_frame, stamp, object_id, self.model_id)
        self._warn_novel(object_id, traj.novelty)
        self.publish(out, feat)
        self.predictions += 1
        self._latency_ms.append(1e3 * (time.monotonic() - t_start))
        self.get_logger().info(
            f"predicted {len(out.states) - 1} steps for '{object_id}' in {1e3 * (time.monotonic() - t_start):.1f} ms:"
            f" final position ({traj.positions[-1][0]:.3f}, {traj.positions[-1][1]:.3f}) m, topple probability "
            f"{out.topple_probability:.2f}")
        steps_in = int(self._param("steps_in"))
        if steps_in > 0:
            self._pending.append(PendingRefinement(
                object_id, t_ns, np.asarray(traj.positions[0]), np.asarray(traj.orientations[0]), lin, ang, feat,
                time.monotonic() + steps_in * float(self.predictor.dt) * 3 + 2.0))

    def _on_refine_timer(self) -> None:
        """Expire parked twists; re-predict pending pushes as observed states arrive (ros/pending.refine)."""
        if self._parked:
            self._release_parked()
        if self._pending:
            refine(self)

    def observed(self, states: list[ObjectState], onset: PendingRefinement | None = None):
        """Observed ObjectStates of frames 1..K after the push -> the Predictor's `observed` argument (onset: the
        push's PendingRefinement, with state_source perception: the tracker's first state gets its velocity from
        the onset, requests.observed_steps)."""
        for st in states:
            self.check_frame(st.header.frame_id, "observed state")
        return observed_steps(states, onset if self._perception else None)

    # --------------------------------------------------------------------------------------- service helpers
    def request_shape(self, req, stamp_ns: int | None):
        """(object_id, cloud points or None, shape code or None) of a request naming a cloud or an object_id."""
        if req.cloud.width * req.cloud.height > 0 or len(req.cloud.data) > 0:
            if req.cloud.header.frame_id not in ("", self.table_frame):
                self.check_frame(req.cloud.header.frame_id, "cloud")
            try:
                pts = cloud_to_xyz(req.cloud, max_points=100_000, rng=np.random.default_rng(0))
            except ValueError as exc:
                raise RequestError(f"cloud: {exc}") from None
            if len(pts) < 3:
                raise RequestError(f"cloud has {len(pts)} finite points; at least 3 are needed")
            return req.object_id or "cloud", pts, None
        if not req.object_id and not self._latest_feature_id:
            raise RequestError("request has neither a cloud nor an object_id, and no shape feature was received")
        object_id = self.target_object(req.object_id)
        return object_id, None, self.shape_code(self.select_feature(object_id, stamp_ns))

    def _warn_novel(self, object_id: str, novelty: float) -> None:
        """A throttled warning when a prediction's input lies beyond 99.5 % of the training inputs (the message
        carries the number: PredictedTrajectory.novelty)."""
        if novelty > 1.0:
            self._warn_log(f"the prediction for '{object_id}' lies outside the model's training data (novelty "
                           f"{novelty:.1f} > 1): treat it with caution", "novel input")

    def refuse(self, service: str, res, exc: Exception):
        """A failed response with the reason: bad inputs (ValueError) are counted, anything else is logged."""
        if isinstance(exc, ValueError):  # RequestError, PlanningError or the Predictor refusing an input
            res.success, res.message = False, str(exc)
            self.rejected += 1
            self.last_error = res.message
            self._warn_log(f"{service} refused: {res.message}", res.message)
        else:
            res.success, res.message = False, f"internal error: {type(exc).__name__}: {exc}"
            self.get_logger().error(res.message)
        return res

    # ---------------------------------------------------------------------------------------------- service
    def _on_service(self, req: PredictTrajectory.Request,
                    res: PredictTrajectory.Response) -> PredictTrajectory.Response:
        t_start = time.monotonic()
        try:
            self.check_frame(req.header.frame_id, "request header")
            horizon = self.horizon(req.horizon)
            lin, ang = twist_to_numpy(req.initial_twist)
            self.check_velocity(lin, ang)
            try:
                position, orientation = pose_to_numpy(req.initial_pose, zero_is_identity=True)
            except ValueError as exc:
                raise RequestError(f"initial_pose: {exc}") from None
            stamp_ns = time_to_ns(req.header.stamp)
            object_id, pts, shape = self.request_shape(req, stamp_ns if stamp_ns > 0 else None)
            if pts is not None:
                check_pose_on_cloud(position, pts)
                shape = self.predictor.encode(pts)
            observed = self.observed(list(req.observed)) if req.observed else None
            traj = self.predictor.rollout(shape, lin, ang, horizon=horizon, position=position,
                                          orientation=orientation, observed=observed,
                                          spread=bool(self._param("rest_spread")))
        except Exception as exc:  # noqa: BLE001 - answer with the reason, never crash on a request
            return self.refuse("predict_trajectory", res, exc)
        stamp = req.header.stamp if time_to_ns(req.header.stamp) > 0 else self.get_clock().now().to_msg()
        res.trajectory = trajectory_to_msg(traj, self.table_frame, stamp, object_id, self.model_id,
                                           steps_in=len(req.observed))
        self._warn_novel(object_id, traj.novelty)
        if req.include_path:
            res.path = msg_to_path(res.trajectory)
        res.topple_probability = res.trajectory.topple_probability
        res.success = True
        self.predictions += 1
        self._latency_ms.append(1e3 * (time.monotonic() - t_start))
        res.message = f"{horizon} steps in {self._latency_ms[-1]:.1f} ms"
        return res

    def latest_state(self, object_id: str) -> ObjectState | None:
        """The newest object_state received of object_id, or None."""
        with self._lock:
            states = self._states.get(object_id)
            return states[-1] if states else None

    def _on_plan(self, req: PlanPush.Request, res: PlanPush.Response) -> PlanPush.Response:
        return plan_push.answer(self, req, res)


def main(args: list[str] | None = None) -> int:
    return run_node(PredictorNode, "predictor", args)  # single-threaded: see the module docstring


if __name__ == "__main__":
    sys.exit(main())
