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
"""The shipped RViz config and Foxglove layout parse and show only topics the suite publishes."""
from __future__ import annotations

import ast
import json
import re

import yaml

from conftest import ROOT

VIZ = ROOT / "config" / "viz"
#: How the nodes create publishers: plain ones, and the managed nodes' lifecycle publishers (ros/lifecycle.py).
PUBLISHER_CALLS = ("create_publisher", "create_lifecycle_publisher", "configured_publisher")


def published_topics() -> set[str]:
    """Every topic name the suite's nodes create a publisher for (read from their source)."""
    names = set()
    for path in (ROOT / "physdyn_ros" / "nodes").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "attr", "") in PUBLISHER_CALLS \
                    and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant):
                names.add("/" + node.args[1].value.lstrip("/"))
    assert {"/cloud", "/predicted_path", "/predicted_markers", "/diagnostics"} & names, names
    return names | {"/diagnostics"}  # published through ros/diagnostics.py


def test_rviz_config_shows_suite_topics_in_the_table_frame():
    cfg = yaml.safe_load((VIZ / "physdyn.rviz").read_text())
    manager = cfg["Visualization Manager"]
    assert manager["Global Options"]["Fixed Frame"] == "world"
    topics = {d["Topic"]["Value"] for d in manager["Displays"] if "Topic" in d}
    assert {"/cloud", "/predicted_path", "/predicted_markers"} <= topics
    assert topics <= published_topics(), topics - published_topics()


def test_foxglove_layout_shows_suite_topics():
    layout = json.loads((VIZ / "physdyn.foxglove.json").read_text())
    panels = layout["configById"]
    assert set(re.findall(r'"((?:3D|Plot|DiagnosticSummary|RawMessages)![a-z]+)"', json.dumps(layout["layout"]))) \
        == set(panels)
    topics = set(panels["3D!physdyn"]["topics"]) | {panels["RawMessages!physdyn"]["topicPath"]}
    topics |= {p["value"].split(".")[0] for p in panels["Plot!physdyn"]["paths"]}
    assert topics <= published_topics(), topics - published_topics()
