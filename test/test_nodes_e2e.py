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
"""sim -> perception -> predictor end to end, in one process over DDS (real nodes, real model loader)."""
from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import TwistStamped
from rclpy.parameter import Parameter

from physdyn_ros.msg import ObjectState, PredictedTrajectory, ShapeFeature
from physdyn_ros.nodes.perception_node import PerceptionNode
from physdyn_ros.ros.qos import FEATURE_QOS
from physdyn_ros.nodes.predictor_node import PredictorNode
from physdyn_ros.ros.qos import LATCHED
from physdyn_ros.nodes.sim_node import SimNode
from physdyn_ros.ros.qos import STATE_QOS
from physdyn_ros.ros.convert import time_to_ns
from physdyn_ros.srv import PredictTrajectory, PushObject
from test_nodes_support import Spinner, call, tiny_model, wait_for  # noqa: F401 - fixture


def test_push_in_the_sim_is_predicted(rclpy_init, tiny_model):
    model = Parameter("model_path", value=str(tiny_model))
    sim = SimNode(parameter_overrides=[Parameter("real_time_factor", value=0.0),
                                       Parameter("category", value="speaker"),
                                       Parameter("publish_cloud_rate", value=10.0),
                                       Parameter("cloud_source", value="camera")])
    perception = PerceptionNode(parameter_overrides=[model])
    predictor = PredictorNode(parameter_overrides=[model, Parameter("horizon", value=30)])
    user = rclpy_init.create_node("user")
    feats: list[ShapeFeature] = []
    trajs: list[PredictedTrajectory] = []
    twists: list[TwistStamped] = []
    states: list[ObjectState] = []
    user.create_subscription(ShapeFeature, "shape_feature", feats.append, FEATURE_QOS)
    user.create_subscription(PredictedTrajectory, "predicted_trajectory", trajs.append, LATCHED)
    user.create_subscription(TwistStamped, "initial_twist", twists.append, 10)
    user.create_subscription(ObjectState, "object_state", states.append, STATE_QOS)
    push = user.create_client(PushObject, "push")
    service = user.create_client(PredictTrajectory, "predict_trajectory")
    with Spinner(sim, perception, predictor, user, threads=6):
        assert wait_for(lambda: feats, 20), perception.last_error
        assert feats[-1].model_id == predictor.model_id and feats[-1].object_id == "object"
        req = PushObject.Request()
        req.impulse.x, req.impulse.y = 0.4 * sim.sim.mass, 0.2 * sim.sim.mass
        res = call(push, req)
        assert res.success, res.message
        assert wait_for(lambda: twists and trajs, 20), predictor.last_error
        t0 = time_to_ns(twists[0].header.stamp)
        traj = trajs[-1]
        assert wait_for(lambda: not sim._running, 20)
        frame0 = next(s for s in states if time_to_ns(s.header.stamp) == t0)
        # the prediction starts from the true post-push state and is stamped with the push instant
        assert time_to_ns(traj.header.stamp) == t0 and len(traj.states) == 31
        p, q = traj.states[0].pose.position, traj.states[0].pose.orientation
        tp, tq = frame0.pose.position, frame0.pose.orientation
        assert (p.x, p.y, p.z, q.x, q.y, q.z, q.w) == pytest.approx((tp.x, tp.y, tp.z, tq.x, tq.y, tq.z, tq.w),
                                                                     abs=1e-12)
        assert traj.states[0].twist.linear.x == pytest.approx(0.4, rel=1e-6)
        assert traj.states[0].twist.linear.y == pytest.approx(0.2, rel=1e-6)
        assert np.all(np.isfinite([s.pose.position.x for s in traj.states]))
        # the service path on the same object (its latest feature), and on the sim's own cloud
        req = PredictTrajectory.Request(object_id="object", horizon=20, include_path=True)
        req.header.frame_id = "world"
        req.initial_pose = frame0.pose
        req.initial_twist = res.initial_twist
        answer = call(service, req)
        assert answer.success and len(answer.path.poses) == 21, answer.message
        assert predictor.rejected == 0, predictor.last_error
