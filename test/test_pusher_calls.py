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
"""The pusher's service calls over DDS, against a planner that answers late: a plan whose reply does not come within
service_timeout is asked again (a reply DDS dropped held a goal for 40 s, and deactivating the node could not end
it); a push, which must not run twice, is not; deactivating the node ends a pending call at once."""
from __future__ import annotations

import threading
import time

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.parameter import Parameter

from physdyn_ros.nodes.pusher_node import EpisodeError, PusherNode
from physdyn_ros.srv import PlanPush, PushObject
from test_nodes_support import Spinner, wait_for


def test_a_late_plan_is_asked_again_a_push_is_not_and_deactivate_ends_a_call(rclpy_init):
    served: dict[str, list[float]] = {"plan": [], "push": []}
    slow = threading.Event()
    server = rclpy_init.create_node("late_services")

    def plan(_req, res):
        served["plan"].append(time.monotonic())
        if len(served["plan"]) == 1 or slow.is_set():
            time.sleep(3.0)  # answered after the caller gave up on it: as if the reply had been dropped
        res.success = True
        return res

    def push(_req, res):
        served["push"].append(time.monotonic())
        time.sleep(1.0)
        res.success = True
        return res

    group = ReentrantCallbackGroup()
    server.create_service(PlanPush, "late_plan_push", plan, callback_group=group)
    server.create_service(PushObject, "late_push_object", push, callback_group=group)
    pusher = PusherNode(namespace="calls", parameter_overrides=[
        Parameter("plan_service", value="/late_plan_push"), Parameter("push_service", value="/late_push_object"),
        Parameter("service_timeout", value=0.5)])
    with Spinner(server, pusher, threads=6):
        start = time.monotonic()
        assert pusher._call(pusher.plan_client, PlanPush.Request(), "plan_push").success
        assert time.monotonic() - start < 2.5 and len(served["plan"]) == 2, served
        # a push is sent once, and its answer waited for beyond service_timeout
        assert pusher._call(pusher.push_client, PushObject.Request(), "push_object", idempotent=False).success
        assert len(served["push"]) == 1
        # a call pending when the node is deactivated ends at once, with the reason
        slow.set()
        caught: list[BaseException] = []

        def call() -> None:
            try:
                pusher._call(pusher.plan_client, PlanPush.Request(), "plan_push")
            except EpisodeError as exc:
                caught.append(exc)

        worker = threading.Thread(target=call)
        worker.start()
        assert wait_for(lambda: len(served["plan"]) == 3, 5.0)
        stopped = time.monotonic()
        pusher.trigger_deactivate()
        worker.join(5.0)
        assert caught and "inactive" in str(caught[0]) and time.monotonic() - stopped < 1.0, caught
        pusher.trigger_activate()
        assert pusher.is_active
