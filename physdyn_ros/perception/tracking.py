"""Object ids that stay the same from cloud to cloud: nearest-centroid tracking with a gate (no ROS).

Each track keeps the object's last centroid, a velocity estimate and the time it was last seen. For a new cloud
(time t, the cloud's stamp in seconds) every track predicts where its object is now (constant velocity); a
detection's distance to a track is the smaller of its distances to that prediction and to the last centroid (the
object may have stopped since), and detections are matched to tracks by minimum total distance (Hungarian
assignment) among pairs closer than `gate`. A matched detection keeps the track's id; an unmatched one starts a new
track with a new id (`<prefix><n>`, n counting from 1 and never reused by this tracker); a track not matched for
more than `timeout` seconds is retired, so an object that comes back after that gets a new id. Time going backwards
by more than `timeout` (a bag played again) clears every track.

Limits: two objects that swap places within one cloud interval, or an object that moves farther than `gate`
beyond its predicted position between two clouds (a hard push seen at a low cloud rate), get swapped or new ids.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Track:
    id: str
    centroid: np.ndarray  # m, table frame
    velocity: np.ndarray  # m/s
    last_seen: float  # s
    hits: int = 1

    def predict(self, t: float) -> np.ndarray:
        return self.centroid + self.velocity * max(0.0, t - self.last_seen)


class Tracker:
    def __init__(self, prefix: str = "object_", gate: float = 0.1, timeout: float = 2.0,
                 max_speed: float = 5.0) -> None:
        self.prefix, self.gate, self.timeout, self.max_speed = prefix, float(gate), float(timeout), float(max_speed)
        self.tracks: list[Track] = []
        self.count = 0  # ids handed out so far
        self._last_t: float | None = None

    def configure(self, prefix: str, gate: float, timeout: float) -> None:
        """New settings (parameters changed at run time); a new prefix applies to new tracks only."""
        self.prefix, self.gate, self.timeout = prefix, float(gate), float(timeout)

    def _age(self, t: float) -> None:
        if self._last_t is not None and t < self._last_t - self.timeout:
            self.tracks.clear()  # time went backwards: a replayed bag, a reset sim clock
            self._last_t = t
        self._last_t = t if self._last_t is None else max(self._last_t, t)
        self.tracks = [tr for tr in self.tracks if t - tr.last_seen <= self.timeout]

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
        rows, cols = linear_sum_assignment(np.where(dist <= self.gate, dist, big))
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

    def update(self, centroids, t: float) -> list[str]:
        """Ids of the detections (centroids (K, 3), m) seen at time t (s), in their order."""
        c = np.asarray(centroids, dtype=np.float64).reshape(-1, 3)
        self._age(t)
        matched = self._match(c, t)
        ids = []
        for i in range(len(c)):
            if i in matched:
                tr = self.tracks[matched[i]]
                self._update(tr, c[i], t)
            else:
                tr = self._new(c[i], t)
            ids.append(tr.id)
        return ids

    def follow(self, centroids, t: float, track_id: str) -> int | None:
        """Single-object mode: the index of the detection that continues the one track `track_id` (the detection
        nearest its predicted position, within the gate), else of the first detection (the largest, as the
        scene lists them) which restarts the track; None without detections."""
        c = np.asarray(centroids, dtype=np.float64).reshape(-1, 3)
        self._age(t)
        self.tracks = [tr for tr in self.tracks if tr.id == track_id]
        if not len(c):
            return None
        if self.tracks:
            tr = self.tracks[0]
            dist = np.minimum(np.linalg.norm(c - tr.predict(t), axis=1), np.linalg.norm(c - tr.centroid, axis=1))
            best = int(np.argmin(dist))
            if dist[best] <= self.gate:
                self._update(tr, c[best], t)
                return best
        self.tracks = [self._new(c[0], t, track_id)]
        return 0
