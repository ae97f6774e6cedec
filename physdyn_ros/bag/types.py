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
"""Message types of the bags: a rosbags typestore (ROS 2 Jazzy + the suite's own types), the suite's topics.

The suite's types are registered from their .msg text (repository msg/ or an installed share/physdyn_ros/msg),
so the bag carries their full definitions and RIHS01 hashes, equal to the ones rosidl computes (a test compares
them with the publishers' type hashes). Other types unknown to the Jazzy store are looked up the same way in
share/<package>/msg/ of the ROS prefixes (AMENT_PREFIX_PATH, this Python environment). No rclpy here.
"""
from __future__ import annotations

import os
import re
import sys
import threading
from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

PACKAGE = "physdyn_ros"
_REPO_MSG_DIR = Path(__file__).resolve().parents[2] / "msg"

#: The suite's topics (relative names, as the nodes publish them) -> fully qualified message type.
SUITE_TOPICS: dict[str, str] = {
    "cloud": "sensor_msgs/msg/PointCloud2",
    "object_state": "physdyn_ros/msg/ObjectState",
    "odom": "nav_msgs/msg/Odometry",
    "object_pose": "geometry_msgs/msg/PoseStamped",
    "initial_twist": "geometry_msgs/msg/TwistStamped",
    "shape_feature": "physdyn_ros/msg/ShapeFeature",
    "predicted_trajectory": "physdyn_ros/msg/PredictedTrajectory",
    "predicted_path": "nav_msgs/msg/Path",
    "predicted_markers": "visualization_msgs/msg/MarkerArray",
}

_TYPE_RE = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)/(?:msg/)?([A-Za-z][A-Za-z0-9]*)$")
_lock = threading.Lock()
_store: Typestore | None = None


def normalize_type(name: str) -> str:
    """'pkg/msg/Type', 'pkg/Type' or 'pkg.msg.Type' -> 'pkg/msg/Type' (what rosbag2 stores); ValueError else."""
    text = name.strip().replace(".", "/")
    m = _TYPE_RE.match(text)
    if not m:
        raise ValueError(f"bad message type {name!r}: expected package/msg/Type, e.g. geometry_msgs/msg/PoseStamped")
    return f"{m.group(1)}/msg/{m.group(2)}"


def _msg_dirs(package: str) -> list[Path]:
    """Folders that may hold package's .msg files, most specific first."""
    dirs = [_REPO_MSG_DIR] if package == PACKAGE else []
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p] + [sys.prefix]
    dirs += [Path(p) / "share" / package / "msg" for p in prefixes]
    return [d for d in dirs if d.is_dir()]


def _find_msg(msgtype: str) -> Path | None:
    package, _, name = msgtype.split("/")
    for d in _msg_dirs(package):
        path = d / f"{name}.msg"
        if path.is_file():
            return path
    return None


def _register(store: Typestore, msgtype: str, seen: set[str]) -> None:
    """Register msgtype and, recursively, the types its fields use, from .msg files."""
    if msgtype in store.fielddefs or msgtype in seen:
        return
    seen.add(msgtype)
    path = _find_msg(msgtype)
    if path is None:
        package, name = msgtype.split('/')[0], msgtype.split('/')[-1]
        raise ValueError(f"unknown message type {msgtype!r}: not a ROS 2 Jazzy type and no {name}.msg "
                         f"found in share/{package}/msg of the ROS prefixes (source its workspace)")
    types = get_types_from_msg(path.read_text(), msgtype)
    _register_with_dependencies(store, types, seen)


def _register_with_dependencies(store: Typestore, types: dict, seen: set[str]) -> None:
    """Register parsed types after (recursively, from .msg files) the types their fields use."""
    for _, fields in types.values():
        for _, (kind, arg) in fields:
            ref = arg[0][1] if isinstance(arg, tuple) and arg and isinstance(arg[0], tuple) else arg
            if isinstance(ref, str) and "/" in ref:
                _register(store, ref, seen)
    store.register(types)


def typestore() -> Typestore:
    """The shared typestore: ROS 2 Jazzy types + the suite's types (built once per process)."""
    global _store
    with _lock:
        if _store is None:
            store = get_typestore(Stores.ROS2_JAZZY)
            for name in ("ObjectState", "ShapeFeature", "PredictedTrajectory"):
                _register(store, f"{PACKAGE}/msg/{name}", set())
            _store = store
        return _store


def ensure_type(msgtype: str) -> str:
    """Normalize msgtype and make sure the typestore can describe it (ValueError naming the problem if not)."""
    msgtype = normalize_type(msgtype)
    store = typestore()
    with _lock:
        if msgtype not in store.fielddefs:
            _register(store, msgtype, set())
    return msgtype


#: Fields appended to the suite's types since bags were first recorded, one tuple per addition, oldest first: a
#: message recorded before an addition is read with the definition without it and the later ones (those fields
#: are then absent from the decoded message).
ADDED_FIELDS: dict[str, tuple[tuple[str, ...], ...]] = {f"{PACKAGE}/msg/PredictedTrajectory": (
    ("novelty",), ("rest_position_spread", "rest_yaw_spread", "topple_probability_spread"))}
_legacy: dict[tuple[str, int], Typestore] = {}


def _legacy_store(msgtype: str, generation: int = 0) -> Typestore:
    """A typestore whose msgtype lacks the fields of addition `generation` and the later ones (built once)."""
    with _lock:
        if (msgtype, generation) not in _legacy:
            store = get_typestore(Stores.ROS2_JAZZY)
            path = _find_msg(msgtype)
            assert path is not None
            added = {f for fields in ADDED_FIELDS[msgtype][generation:] for f in fields}
            lines = [ln for ln in path.read_text().splitlines()
                     if not (ln.split("#")[0].split() and ln.split("#")[0].split()[-1] in added)]
            _register_with_dependencies(store, get_types_from_msg("\n".join(lines) + "\n", msgtype), {msgtype})
            _legacy[(msgtype, generation)] = store
        return _legacy[(msgtype, generation)]


def deserialize(data: bytes | memoryview, msgtype: str):
    """CDR bytes -> a rosbags message object (same field names as the ROS message). A suite message recorded
    before a field was added (ADDED_FIELDS) is read with the older definition."""
    try:
        return typestore().deserialize_cdr(data, msgtype)
    except Exception:
        if msgtype not in ADDED_FIELDS:
            raise
    # newest definition first: rosbags refuses a message with more than 3 bytes left over, which every addition so
    # far leaves, but an addition of a bool or a byte would let an older definition read a newer message
    for generation in reversed(range(len(ADDED_FIELDS[msgtype]))):
        try:
            return _legacy_store(msgtype, generation).deserialize_cdr(data, msgtype)
        except Exception:
            if generation == 0:
                raise
    raise AssertionError("unreachable")


def serialize(msg, msgtype: str) -> bytes:
    return bytes(typestore().serialize_cdr(msg, msgtype))
