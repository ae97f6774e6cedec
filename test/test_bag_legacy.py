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
"""Bags recorded before a field was added to one of the suite's messages still read (bag/types.ADDED_FIELDS)."""
from __future__ import annotations

import math

from physdyn_ros.bag import types as T


def test_a_prediction_recorded_before_novelty_existed_still_decodes():
    """Review finding: PredictedTrajectory gained `novelty`; a prediction serialized with the older definition
    raised a SerdeError in every bag reader (report, bag2dataset)."""
    msgtype = "physdyn_ros/msg/PredictedTrajectory"
    old = T._legacy_store(msgtype)
    assert "novelty" not in [name for name, _ in old.fielddefs[msgtype][1]]
    types = old.types
    state = types["physdyn_ros/msg/ObjectState"]
    stamp = types["builtin_interfaces/msg/Time"](sec=3, nanosec=0)
    header = types["std_msgs/msg/Header"](stamp=stamp, frame_id="world")
    point = types["geometry_msgs/msg/Point"](x=0.1, y=0.2, z=0.03)
    quat = types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    vec = types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    s = state(header=header, object_id="box", pose=types["geometry_msgs/msg/Pose"](position=point, orientation=quat),
              twist=types["geometry_msgs/msg/Twist"](linear=vec, angular=vec), toppled=False, topple_probability=0.1)
    msg = types[msgtype](header=header, object_id="box", model_id="m",
                         time_step=types["builtin_interfaces/msg/Duration"](sec=0, nanosec=66_666_667), steps_in=0,
                         states=[s, s], topple_probability=0.25)
    data = bytes(old.serialize_cdr(msg, msgtype))
    out = T.deserialize(data, msgtype)
    assert len(out.states) == 2 and math.isclose(out.topple_probability, 0.25)
    assert math.isclose(out.states[1].pose.position.y, 0.2)
    # a current message reads with the current definition, novelty included
    now = T.typestore().types[msgtype](header=header, object_id="box", model_id="m",
                                       time_step=msg.time_step, steps_in=0, states=[s], topple_probability=0.5,
                                       novelty=0.3, rest_position_spread=0.02, rest_yaw_spread=0.1,
                                       topple_probability_spread=0.05)
    back = T.deserialize(bytes(T.serialize(now, msgtype)), msgtype)
    assert math.isclose(back.novelty, 0.3, rel_tol=1e-6)
    assert math.isclose(back.rest_position_spread, 0.02, rel_tol=1e-6)


def test_a_prediction_with_novelty_but_no_spread_keeps_its_novelty():
    """A prediction recorded after `novelty` and before the spread fields reads with that generation's
    definition: its novelty survives (the single legacy definition, without novelty, lost it)."""
    msgtype = "physdyn_ros/msg/PredictedTrajectory"
    mid = T._legacy_store(msgtype, 1)
    fields = [name for name, _ in mid.fielddefs[msgtype][1]]
    assert "novelty" in fields and "rest_position_spread" not in fields
    types = mid.types
    header = types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=3, nanosec=0),
                                          frame_id="world")
    msg = types[msgtype](header=header, object_id="can", model_id="m",
                         time_step=types["builtin_interfaces/msg/Duration"](sec=0, nanosec=66_666_667), steps_in=0,
                         states=[], topple_probability=0.25, novelty=1.5)
    out = T.deserialize(bytes(mid.serialize_cdr(msg, msgtype)), msgtype)
    assert out.object_id == "can" and math.isclose(out.novelty, 1.5)
