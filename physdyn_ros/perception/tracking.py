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
"""Object ids that stay the same from cloud to cloud: nearest-centroid tracking with a gate (no ROS).

Each track keeps the object's last centroid, a velocity estimate and the time it was last seen. For a new cloud
(time t, the cloud's stamp in seconds) every track predicts where its object is now (constant velocity); a
detection's distance to a track is the smaller of its distances to that prediction and to the last centroid (the
object may have stopped since), and detections are matched to tracks by minimum total distance (Hungarian
assignment) among pairs closer than `gate`. A matched detection keeps the track's id; an unmatched one starts a new
track with a new id (`<prefix><n>`, n counting from 1 and never handed to another object by this tracker). A track
not matched for more than `timeout` seconds is lost: no longer matched by distance, but its id waits `memory`
seconds for an object of its shape (the second chance below: an object hidden behind another for a few seconds
comes back under its id); after that, or at once without a shape signature, it is retired and its id is never
used again. Time going backwards by more than `timeout` (a bag played again) retires every track.

Second chance (when the caller gives each detection's `shape_signature`): a detection left unmatched takes the
id of an unmatched or lost track within `reach` of where that was last seen whose signature agrees (height and x-y
spread within `shape_tolerance`, relative; unmatched tracks first, then the lost): a hard push seen at a low cloud
rate moves an object beyond the gate in one interval, and an object that left the view comes back elsewhere; the
signature keeps a different object from inheriting the id.

Fragments: a detection no larger than an established track's object (YOUNG_HITS hits or more, with a signature;
each signature component at most 1 + `shape_tolerance` times the track's) and under FRAGMENT times it in height
span or larger x-y spread is a part of that object (a noisy depth image's cluster that kept only one end of a long
box, an object half hidden) where it is matched to the track, or, left unmatched, where the track is unmatched too
and the part lies within EXTENT times the track's larger x-y spread of its centroid (inside the object; beyond the
gate for a long object; one part per track and cloud). It gets the track's id, but the track holds its centroid,
velocity, signature and last-seen time, and `parts` lists it (the caller's feature and pose of the object should
not come from a part either). Followed, such a part would drag the track off its object, and the whole object
seen again on the next cloud would be beyond the gate and start a new id; given a new id, a part that comes back
every few clouds would keep a phantom track alive beside the object. A part stands in for its object for at most
PART_HOLD s after the object's last whole view: a view that stays smaller is the object's new view (a wedge turned
to show its thin side), followed from then on with its own signature. An object that topples is no part of itself:
its x-y spread grows.

Duplicates: a track seen fewer than YOUNG_HITS times costs YOUNG_COST gates more in the assignment, and an
unmatched track within DUPLICATE gates of a detection an older track took is lost (a sparse object's cluster that
splits for one cloud starts a second track on one half, which would otherwise take the object every other cloud).

Limits: two objects that swap places within one cloud interval get swapped ids; without signatures, an object that
moves farther than `gate` beyond its predicted position between two clouds gets a new id; two objects of one
shape (within `shape_tolerance`) can take each other's id when one comes back from being lost.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

#: A track matched fewer than YOUNG_HITS times costs YOUNG_COST gates more in the assignment.
YOUNG_HITS = 15
YOUNG_COST = 0.5
#: A detection of an established track whose height span or larger x-y spread is under FRAGMENT times the track's
#: is a part of the object: the track holds its state (module docstring). Under depth noise a whole object's
#: components vary by up to a third between clouds.
FRAGMENT = 0.5
#: ... for at most PART_HOLD s since its object's last whole view: a fragment lasts a cloud or two, while a view
#: that stays smaller is the object's new view (it turned) and is followed.
PART_HOLD = 0.3
#: ... and lies within EXTENT times the track's larger x-y spread (a standard deviation) of its centroid: a uniform
#: rod's ends lie 1.7 of them from its middle.
EXTENT = 2.0
#: An unmatched track this many gates from a detection an older track took is a duplicate of that track.
DUPLICATE = 0.5
#: Retirements kept for a caller that has not taken them (Tracker.take_retired): the latest ones.
RETIRED_KEPT = 64


@dataclass
class Track:
    id: str
    centroid: np.ndarray  # m, table frame
    velocity: np.ndarray  # m/s
    last_seen: float  # s
    hits: int = 1
    signature: np.ndarray | None = None  # shape_signature of its detections (running mean)

    def predict(self, t: float) -> np.ndarray:
        return self.centroid + self.velocity * max(0.0, t - self.last_seen)

    def smaller(self, signature: np.ndarray | None, tolerance: float) -> bool:
        """Whether a detection of this signature is small enough to be only a part of the track's object (module
        docstring; tolerance: the tracker's shape_tolerance)."""
        if signature is None or self.signature is None or self.hits < YOUNG_HITS:
            return False
        if np.any(signature > (1.0 + tolerance) * self.signature):  # larger in some way: not a part of it
            return False
        return bool(signature[0] < FRAGMENT * self.signature[0] or signature[2] < FRAGMENT * self.signature[2])

    def fragment(self, signature: np.ndarray | None, tolerance: float, t: float) -> bool:
        """smaller(), within PART_HOLD s of the last whole view at time t: a part that stands in for its object."""
        return t - self.last_seen <= PART_HOLD and self.smaller(signature, tolerance)

    def inside(self, centroids: np.ndarray) -> np.ndarray:
        """Which of the centroids (N, 3) lie within EXTENT times the larger x-y spread of the track's centroid (on
        its object); none without a signature."""
        if self.signature is None:
            return np.zeros(len(centroids), dtype=bool)
        return np.linalg.norm(centroids[:, :2] - self.centroid[:2], axis=1) <= EXTENT * self.signature[2]

    def take_signature(self, signature: np.ndarray, tolerance: float) -> None:
        """The running signature after a followed detection; a view that stayed smaller past PART_HOLD is the
        object's new view (it turned), and its signature starts over."""
        if self.signature is None or self.smaller(signature, tolerance):
            self.signature = signature
        else:
            self.signature = 0.8 * self.signature + 0.2 * signature


def shape_signature(points: np.ndarray) -> np.ndarray:
    """(3,) m, unchanged by a turn about the table's z axis: the points' height span and the square roots of the
    two eigenvalues of their x-y covariance."""
    pts = np.asarray(points, dtype=np.float64)
    xy = pts[:, :2] - pts[:, :2].mean(axis=0)
    vals = np.linalg.eigvalsh(xy.T @ xy / max(1, len(xy)))
    return np.array([float(np.ptp(pts[:, 2])), *np.sqrt(np.maximum(vals, 0.0))])


class Tracker:
    def __init__(self, prefix: str = "object_", gate: float = 0.1, timeout: float = 2.0,
                 max_speed: float = 5.0, reach: float = 0.5, shape_tolerance: float = 0.25,
                 memory: float = 30.0) -> None:
        self.prefix, self.gate, self.timeout, self.max_speed = prefix, float(gate), float(timeout), float(max_speed)
        self.reach, self.shape_tolerance, self.memory = float(reach), float(shape_tolerance), float(memory)
        self.tracks: list[Track] = []
        self.lost: list[Track] = []  # not seen for longer than timeout; their ids wait for their shapes
        # (id, why) of the tracks lost since the caller last took them (the latest RETIRED_KEPT)
        self.losses: deque[tuple[str, str]] = deque(maxlen=RETIRED_KEPT)
        self.count = 0  # ids handed out so far
        # (id, why) of the tracks ended since the caller last took them (the latest RETIRED_KEPT)
        self.retired: deque[tuple[str, str]] = deque(maxlen=RETIRED_KEPT)
        self._last_t: float | None = None
        self.parts: list[int] = []  # the last update's detections that were parts of a tracked object

    def configure(self, prefix: str, gate: float, timeout: float, memory: float | None = None) -> None:
        """New settings (parameters changed at run time); a new prefix applies to new tracks only."""
        self.prefix, self.gate, self.timeout = prefix, float(gate), float(timeout)
        if memory is not None:
            self.memory = float(memory)

    def _age(self, t: float) -> None:
        if self._last_t is not None and t < self._last_t - self.timeout:
            # time went backwards: a replayed bag, a reset sim clock
            why = f"time went back {self._last_t - t:.1f} s (a replayed bag, a reset clock)"
            self.retired += [(tr.id, why) for tr in self.tracks + self.lost]
            self.tracks.clear()
            self.lost.clear()
            self._last_t = t
        self._last_t = t if self._last_t is None else max(self._last_t, t)
        for tr in [tr for tr in self.tracks if t - tr.last_seen > self.timeout]:
            self._lose(tr, f"not seen for {t - tr.last_seen:.1f} s (timeout {self.timeout:g} s)",
                       keep=self.memory > t - tr.last_seen)
        self.tracks = [tr for tr in self.tracks if t - tr.last_seen <= self.timeout]
        self.retired += [(tr.id, f"not seen for {t - tr.last_seen:.1f} s (lost, track_memory {self.memory:g} s)")
                         for tr in self.lost if t - tr.last_seen > self.memory]
        self.lost = [tr for tr in self.lost if t - tr.last_seen <= self.memory]

    def _lose(self, tr: Track, why: str, keep: bool = True) -> None:
        """A track leaves the live list: lost (its id waits for its shape) when it has a signature and keep
        allows, else retired. The caller removes it from self.tracks."""
        if tr.signature is not None and keep:
            self.lost.append(tr)
            self.losses.append((tr.id, why))
        else:
            self.retired.append((tr.id, why))

    def take_losses(self) -> list[tuple[str, str]]:
        """(id, why) of every track lost since the last call, oldest first."""
        out = list(self.losses)
        self.losses.clear()
        return out

    def take_retired(self) -> list[tuple[str, str]]:
        """(id, why) of every track ended since the last call, oldest first; an ended id is never handed out
        again (single-object mode's fixed id aside, whose restart is listed too)."""
        out = list(self.retired)
        self.retired.clear()
        return out

    def _match(self, centroids: np.ndarray, t: float) -> dict[int, int]:
        """detection index -> track index, for pairs within the gate (minimum total distance)."""
        if not self.tracks or not len(centroids):
            return {}
        from scipy.optimize import linear_sum_assignment

        pred = np.array([tr.predict(t) for tr in self.tracks])
        last = np.array([tr.centroid for tr in self.tracks])
        dist = np.minimum(np.linalg.norm(centroids[:, None, :] - pred[None, :, :], axis=2),
                          np.linalg.norm(centroids[:, None, :] - last[None, :, :], axis=2))
        big = 1e6
        # an established track wins over a young one at a similar distance: a sparse object's cloud that splits
        # for one frame starts a young track on one half, which must not take the whole object's id next frame
        young = np.array([YOUNG_COST * self.gate if tr.hits < YOUNG_HITS else 0.0 for tr in self.tracks])
        rows, cols = linear_sum_assignment(np.where(dist <= self.gate, dist + young[None, :], big))
        return {int(r): int(c) for r, c in zip(rows, cols) if dist[r, c] <= self.gate}

    def _update(self, tr: Track, c: np.ndarray, t: float) -> None:
        dt = t - tr.last_seen
        if dt > 1e-6:
            v = (c - tr.centroid) / dt
            v = v if tr.hits == 1 else 0.5 * tr.velocity + 0.5 * v
            speed = float(np.linalg.norm(v))
            tr.velocity = v * (self.max_speed / speed) if speed > self.max_speed else v
        tr.centroid, tr.last_seen, tr.hits = c, max(tr.last_seen, t), tr.hits + 1

    def _new(self, c: np.ndarray, t: float, track_id: str | None = None) -> Track:
        if track_id is None:
            self.count += 1
            track_id = f"{self.prefix}{self.count}"
        tr = Track(track_id, c, np.zeros(3), t)
        self.tracks.append(tr)
        return tr

    def _rematch(self, c: np.ndarray, sig: np.ndarray, matched: dict[int, int]) -> dict[int, int]:
        """The second chance of the module docstring: unmatched detection index -> unmatched track index.
        Indices from len(self.tracks) on are the lost tracks'."""
        from scipy.optimize import linear_sum_assignment

        dets = [i for i in range(len(c)) if i not in matched]
        taken = set(matched.values())
        pool = self.tracks + self.lost
        free = [j for j, tr in enumerate(pool) if j not in taken and tr.signature is not None]
        if not dets or not free:
            return {}
        dist = np.linalg.norm(c[dets][:, None, :] - np.array([pool[j].centroid for j in free])[None], axis=2)
        ref = np.array([pool[j].signature for j in free])
        rel = np.abs(sig[dets][:, None, :] - ref[None]) / np.maximum(ref[None], 0.01)
        ok = (dist <= self.reach) & (rel.max(axis=2) <= self.shape_tolerance)
        # a live track beats a lost one: a lost track's distance counts after every live one's
        cost = dist + np.array([self.reach if j >= len(self.tracks) else 0.0 for j in free])[None]
        rows, cols = linear_sum_assignment(np.where(ok, cost, 1e6))
        return {dets[r]: free[k] for r, k in zip(rows, cols) if ok[r, k]}

    def _parts(self, c: np.ndarray, sig: np.ndarray, matched: dict[int, int], again: dict[int, int],
               t: float) -> dict[int, int]:
        """Unmatched detection index -> index of the unmatched live track whose object it is a part of (the
        module docstring's fragments), nearest first."""
        taken = set(matched.values()) | {j for j in again.values() if j < len(self.tracks)}
        pairs = []
        for i in range(len(c)):
            if i in matched or i in again:
                continue
            for j, tr in enumerate(self.tracks):
                if j in taken or not tr.fragment(sig[i], self.shape_tolerance, t):
                    continue
                if tr.inside(c[i:i + 1])[0]:
                    pairs.append((float(np.linalg.norm(c[i, :2] - tr.centroid[:2])), i, j))
        out: dict[int, int] = {}
        for _, i, j in sorted(pairs):
            if i not in out and j not in out.values():
                out[i] = j
        return out

    def _drop_duplicates(self, c: np.ndarray, t: float, matched: dict[int, int]) -> None:
        """An unmatched track within DUPLICATE gates of a detection that an older track took is a second track on
        one object (started on half of a split cluster): it is lost (its id may still come back by shape; retired
        without a signature) instead of taking the object every other cloud. matched (detection -> track index)
        is re-indexed in place."""
        taken = set(matched.values())
        owner: dict[int, str] = {}  # duplicate track index -> the id of the track that has its object
        for j, tr in enumerate(self.tracks):
            if j in taken:
                continue
            for i, k in matched.items():
                near = min(float(np.linalg.norm(c[i] - tr.centroid)), float(np.linalg.norm(c[i] - tr.predict(t))))
                if near <= DUPLICATE * self.gate and self.tracks[k].hits > tr.hits:
                    owner[j] = self.tracks[k].id
                    break
        if not owner:
            return
        for j, other in owner.items():
            self._lose(self.tracks[j], f"a second track on the object of {other}")
        keep = [j for j in range(len(self.tracks)) if j not in owner]
        index = {old: new for new, old in enumerate(keep)}
        self.tracks = [self.tracks[j] for j in keep]
        for i in matched:
            matched[i] = index[matched[i]]

    def update(self, centroids, t: float, signatures=None) -> list[str]:
        """Ids of the detections (centroids (K, 3), m) seen at time t (s), in their order; `parts` then lists the
        indices of those that are only parts of their objects. signatures: (K, 3) shape_signature of each
        detection (optional: enables the second chance and the parts)."""
        c = np.asarray(centroids, dtype=np.float64).reshape(-1, 3)
        sig = None if signatures is None else np.asarray(signatures, dtype=np.float64).reshape(-1, 3)
        self._age(t)
        matched = self._match(c, t)
        self._drop_duplicates(c, t, matched)
        again = self._rematch(c, sig, matched) if sig is not None else {}
        parts = self._parts(c, sig, matched, again, t) if sig is not None else {}
        pool = self.tracks + self.lost
        back = [pool[j] for j in again.values() if j >= len(self.tracks)]
        self.lost = [tr for tr in self.lost if all(tr is not b for b in back)]
        self.tracks += back
        ids = []
        self.parts = []
        for i in range(len(c)):
            part = self.tracks[parts[i]] if i in parts else None
            if (part is None and i in matched and sig is not None
                    and pool[matched[i]].fragment(sig[i], self.shape_tolerance, t)):
                part = pool[matched[i]]
            if part is not None:  # seen, but neither moved nor kept alive by it
                self.parts.append(i)
                ids.append(part.id)
                continue
            if i in matched or i in again:
                tr = pool[matched[i] if i in matched else again[i]]
                if i in again:  # a jump, not a velocity: the constant-velocity prediction starts over
                    tr.centroid, tr.velocity = c[i], np.zeros(3)
                self._update(tr, c[i], t)
            else:
                tr = self._new(c[i], t)
            if sig is not None:
                tr.take_signature(sig[i], self.shape_tolerance)
            ids.append(tr.id)
        return ids

    def follow(self, centroids, t: float, track_id: str, signatures=None) -> int | None:
        """Single-object mode: the index of the detection that continues the one track `track_id` (the whole
        detection nearest its predicted position, within the gate; else, with `signatures`, a part of its object
        (module docstring: `parts` then lists it, and the track holds), or the second chance: a push that moved
        the object beyond the gate between two clouds), else of the first detection (the largest, as the scene
        lists them) which restarts the track; None without detections."""
        c = np.asarray(centroids, dtype=np.float64).reshape(-1, 3)
        sig = None if signatures is None else np.asarray(signatures, dtype=np.float64).reshape(-1, 3)
        self._age(t)
        self.parts = []
        self.retired += [(tr.id, f"another object is followed as '{track_id}'") for tr in self.tracks
                         if tr.id != track_id]
        self.tracks = [tr for tr in self.tracks if tr.id == track_id]
        if not len(c):
            return None
        if self.tracks:
            tr = self.tracks[0]
            dist = np.minimum(np.linalg.norm(c - tr.predict(t), axis=1), np.linalg.norm(c - tr.centroid, axis=1))
            part = (np.array([tr.fragment(s, self.shape_tolerance, t) for s in sig]) if sig is not None
                    else np.zeros(len(c), dtype=bool))
            whole = np.flatnonzero(~part & (dist <= self.gate))
            best: int | None = int(whole[np.argmin(dist[whole])]) if len(whole) else None
            if best is None and part.any():
                inside = part & ((dist <= self.gate) | tr.inside(c))
                if inside.any():  # seen, but neither moved nor kept alive by it
                    best = int(np.flatnonzero(inside)[np.argmin(dist[inside])])
                    self.parts = [best]
                    return best
            if best is None:
                jump = [i for i, j in (self._rematch(c, sig, {}) if sig is not None else {}).items() if j == 0]
                best = jump[0] if jump else None
                if best is not None:  # a jump, not a velocity: the constant-velocity prediction starts over
                    tr.centroid, tr.velocity = c[best], np.zeros(3)
            if best is not None:
                self._update(tr, c[best], t)
                if sig is not None:
                    tr.take_signature(sig[best], self.shape_tolerance)
                return best
        if self.tracks:
            self.retired.append((track_id, "lost; the id restarts on another detection (single_object)"))
        self.tracks = [self._new(c[0], t, track_id)]
        if sig is not None:
            self.tracks[0].signature = sig[0]
        return 0
