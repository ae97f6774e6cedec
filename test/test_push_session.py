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
"""PushSession's aim: the goal, corrected by the observed slide ratio, split into legs when one push cannot reach."""
from __future__ import annotations

import math

import numpy as np
import pytest

from physdyn_ros.planning.session import LEG_REACH, PushSession
from physdyn_ros.planning.types import Goal, Pose2D


def test_a_goal_beyond_one_push_becomes_legs_one_push_can_slide():
    session = PushSession(Goal(Pose2D(0.6, 0.0, 0.5), 0.02, 0.2), max_pushes=5)
    aim = session.aim(Pose2D(0.0, 0.0, 0.0), reach=0.328)
    legs = math.ceil(0.6 / (LEG_REACH * 0.328))
    assert aim.pose.xy == pytest.approx([0.6 / legs, 0.0])
    assert aim.ignores_yaw and aim.position_tolerance > 0.02
    assert np.linalg.norm(aim.pose.xy) < 0.328  # one push reaches it
    # within reach: the goal itself, yaw and tolerance as asked
    assert session.aim(Pose2D(0.4, 0.0, 0.0), reach=0.328) == session.goal


def test_a_goal_that_needs_more_pushes_than_are_left_stays_the_goal():
    """The planner then refuses it with the reason (goal unreachable) instead of pushing part of the way."""
    session = PushSession(Goal(Pose2D(0.9, 0.0, 0.0), 0.02, math.pi), max_pushes=2)
    assert session.aim(Pose2D(0.0, 0.0, 0.0), reach=0.3) == session.goal
    assert session.aim(Pose2D(0.0, 0.0, 0.0)) == session.goal  # reach unknown
