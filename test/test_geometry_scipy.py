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
"""The rotation helpers run on scipy.spatial.transform (Rotation, Slerp) and give the hand-written results.

The hand-written implementations they replaced are frozen below (`Old*`, copied verbatim from geometry.py,
sim/simulator.py, ros/convert.py, bag/pushes.py and predictor.py before the change); the new functions must
agree with them to 1e-9 on random inputs (single, batched, N-d and broadcast shapes, rotation vectors beyond pi,
float32 inputs). A quaternion and its negative are the same rotation: results compare up to sign only where the
old function did not fix the sign either.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from physdyn_ros import geometry as geo
from physdyn_ros.conventions import TOPPLE_ANGLE

TOL = 1e-9


# ----------------------------------------------------------------------------------- the frozen implementations
class OldGeometry:
    """physdyn_ros/geometry.py before the move to scipy."""

    @staticmethod
    def f64(x):
        return np.asarray(x, dtype=np.float64)

    @classmethod
    def quat_normalize(cls, q):
        q = cls.f64(q)
        n = np.linalg.norm(q, axis=-1, keepdims=True)
        if not np.all(np.isfinite(n)) or np.any(n < 1e-12):
            raise ValueError("quaternion must be finite and non-zero")
        return q / n

    @classmethod
    def quat_multiply(cls, a, b):
        a, b = cls.f64(a), cls.f64(b)
        ax, ay, az, aw = np.moveaxis(a, -1, 0)
        bx, by, bz, bw = np.moveaxis(b, -1, 0)
        return np.stack([
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ], axis=-1)

    @classmethod
    def quat_conjugate(cls, q):
        q = cls.f64(q)
        return np.concatenate([-q[..., :3], q[..., 3:]], axis=-1)

    @classmethod
    def quat_inverse(cls, q):
        q = cls.f64(q)
        return cls.quat_conjugate(q) / np.sum(q * q, axis=-1, keepdims=True)

    @classmethod
    def quat_rotate(cls, q, v):
        q, v = cls.f64(q), cls.f64(v)
        u, w = q[..., :3], q[..., 3:]
        t = 2.0 * np.cross(u, v)
        return v + w * t + np.cross(u, t)

    @classmethod
    def quat_to_matrix(cls, q):
        x, y, z, w = np.moveaxis(cls.f64(q), -1, 0)
        return np.stack([
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ], axis=-2)

    @classmethod
    def matrix_to_quat(cls, m):
        m = cls.f64(m)
        tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
        cand = np.stack([1 + 2 * m[..., 0, 0] - tr, 1 + 2 * m[..., 1, 1] - tr, 1 + 2 * m[..., 2, 2] - tr, 1 + tr], -1)
        k = np.argmax(cand, axis=-1)
        r = 0.5 * np.sqrt(np.maximum(np.take_along_axis(cand, k[..., None], -1)[..., 0], 1e-300))
        s = 0.25 / r
        q = np.empty(m.shape[:-2] + (4,))
        q0 = np.stack([r, (m[..., 0, 1] + m[..., 1, 0]) * s, (m[..., 0, 2] + m[..., 2, 0]) * s,
                       (m[..., 2, 1] - m[..., 1, 2]) * s], -1)
        q1 = np.stack([(m[..., 0, 1] + m[..., 1, 0]) * s, r, (m[..., 1, 2] + m[..., 2, 1]) * s,
                       (m[..., 0, 2] - m[..., 2, 0]) * s], -1)
        q2 = np.stack([(m[..., 0, 2] + m[..., 2, 0]) * s, (m[..., 1, 2] + m[..., 2, 1]) * s, r,
                       (m[..., 1, 0] - m[..., 0, 1]) * s], -1)
        q3 = np.stack([(m[..., 2, 1] - m[..., 1, 2]) * s, (m[..., 0, 2] - m[..., 2, 0]) * s,
                       (m[..., 1, 0] - m[..., 0, 1]) * s, r], -1)
        for i, qi in enumerate((q0, q1, q2, q3)):
            sel = k == i
            q[sel] = qi[sel]
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
        return np.where(q[..., 3:] < 0, -q, q)

    @classmethod
    def axis_angle_to_quat(cls, rv):
        rv = cls.f64(rv)
        a = np.linalg.norm(rv, axis=-1, keepdims=True)
        half = 0.5 * a
        k = np.where(a > 1e-6, np.sin(half) / np.where(a > 1e-6, a, 1.0), 0.5 - a * a / 48.0)
        return np.concatenate([rv * k, np.cos(half)], axis=-1)

    @classmethod
    def quat_to_axis_angle(cls, q):
        q = cls.f64(q)
        q = np.where(q[..., 3:] < 0, -q, q)
        s = np.linalg.norm(q[..., :3], axis=-1, keepdims=True)
        w = q[..., 3:]
        angle = 2.0 * np.arctan2(s, w)
        k = np.where(s > 1e-8, angle / np.where(s > 1e-8, s, 1.0), 2.0 / np.maximum(w, 1e-12))
        return q[..., :3] * k

    @classmethod
    def quat_angle_between(cls, a, b):
        d = np.abs(np.sum(cls.quat_normalize(a) * cls.quat_normalize(b), axis=-1))
        return 2.0 * np.arccos(np.clip(d, 0.0, 1.0))

    @classmethod
    def axis_angle_to_matrix(cls, rv):
        rv = cls.f64(rv)
        a2 = np.sum(rv * rv, axis=-1)[..., None, None]
        a = np.sqrt(a2)
        small = a2 < 1e-12
        safe = np.where(small, 1.0, a)
        s = np.where(small, 1.0 - a2 / 6.0, np.sin(safe) / safe)
        c = np.where(small, 0.5 - a2 / 24.0, (1.0 - np.cos(safe)) / np.where(small, 1.0, a2))
        x, y, z = rv[..., 0], rv[..., 1], rv[..., 2]
        zero = np.zeros_like(x)
        k = np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)
        return np.eye(3) + s * k + c * (k @ k)

    @classmethod
    def matrix_compose_scan(cls, deltas, r0):
        d = cls.f64(deltas)
        acc = np.concatenate([np.broadcast_to(cls.f64(r0)[..., None, :, :], d.shape[:-3] + (1, 3, 3)), d], axis=-3)
        n, k = acc.shape[-3], 1
        while k < n:
            acc = np.concatenate([acc[..., :k, :, :], acc[..., k:, :, :] @ acc[..., :-k, :, :]], axis=-3)
            k *= 2
        return acc

    @classmethod
    def quat_compose_scan(cls, deltas, q0):
        scan = cls.matrix_compose_scan(cls.quat_to_matrix(cls.quat_normalize(deltas)),
                                       cls.quat_to_matrix(cls.quat_normalize(q0)))
        return cls.matrix_to_quat(scan)

    @classmethod
    def yaw_matrix(cls, psi):
        psi = cls.f64(psi)
        c, s = np.cos(psi), np.sin(psi)
        z, o = np.zeros_like(psi), np.ones_like(psi)
        return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)

    @classmethod
    def yaw_quat(cls, psi):
        psi = cls.f64(psi)
        z = np.zeros_like(psi)
        return np.stack([z, z, np.sin(0.5 * psi), np.cos(0.5 * psi)], -1)


class OldSimulator:
    """The quaternion helpers of physdyn_ros/sim/simulator.py before the move to scipy."""

    @staticmethod
    def quat_mul(a, b):
        ax, ay, az, aw = a
        bx, by, bz, bw = b
        return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                         aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])

    @staticmethod
    def quat_conj(q):
        return np.array([-q[0], -q[1], -q[2], q[3]])

    @staticmethod
    def quat_to_matrix(q):
        x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
        return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                         [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                         [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])

    @staticmethod
    def matrix_to_quat(m):
        m = np.asarray(m, dtype=np.float64)
        tr = np.trace(m)
        if tr > 0:
            s = 2.0 * np.sqrt(tr + 1.0)
            q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
        else:
            i = int(np.argmax(np.diag(m)))
            j, k = (i + 1) % 3, (i + 2) % 3
            s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
            q = [0.0, 0.0, 0.0, (m[k, j] - m[j, k]) / s]
            q[i] = 0.25 * s
            q[j] = (m[j, i] + m[i, j]) / s
            q[k] = (m[k, i] + m[i, k]) / s
        q = np.asarray(q)
        return q / np.linalg.norm(q)

    @staticmethod
    def yaw_quat(yaw):
        return np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])

    @staticmethod
    def tilt_angle(quat):
        q = np.asarray(quat, dtype=np.float64)
        x, y = q[..., 0], q[..., 1]
        n2 = (q * q).sum(-1)
        cos = 1 - 2 * (x * x + y * y) / n2
        return np.arccos(np.clip(cos, -1.0, 1.0))


class OldConvert:
    """The rotation helpers of physdyn_ros/ros/convert.py before the move to scipy."""

    @staticmethod
    def quat_to_matrix(q):
        return OldGeometry.quat_to_matrix(np.asarray(q, dtype=np.float64).reshape(4))

    @staticmethod
    def yaw_quaternion(yaw):
        return np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])

    @staticmethod
    def quat_angle(q1, q2):
        d = abs(float(np.dot(np.asarray(q1, dtype=np.float64), np.asarray(q2, dtype=np.float64))))
        return 2.0 * math.acos(min(1.0, d))

    @classmethod
    def quat_yaw(cls, q):
        r = cls.quat_to_matrix(q)
        return math.atan2(r[1, 0], r[0, 0])

    @classmethod
    def is_toppled(cls, q):
        return bool(cls.quat_to_matrix(q)[2, 2] < math.cos(TOPPLE_ANGLE))


def old_slerp(q0, q1, w):
    """bag/pushes.py's row-wise slerp before the move to scipy (q0, q1 in the same hemisphere)."""
    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    w = np.asarray(w, float)[:, None]
    dot = np.clip(np.sum(q0 * q1, axis=1, keepdims=True), -1.0, 1.0)
    theta = np.arccos(dot)
    sin = np.sin(theta)
    small = sin[:, 0] < 1e-9
    out = np.empty_like(q0)
    a = np.where(small[:, None], 1 - w, np.sin((1 - w) * theta) / np.where(small[:, None], 1.0, sin))
    b = np.where(small[:, None], w, np.sin(w * theta) / np.where(small[:, None], 1.0, sin))
    out[:] = a * q0 + b * q1
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def old_sample_quat(t, quat, times):
    """The orientation part of bag/pushes.sample before the move to scipy."""
    i = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(t) - 1)
    j = np.minimum(i + 1, len(t) - 1)
    span = (t[j] - t[i]).astype(np.float64)
    w = np.where(span > 0, (times - t[i]).astype(np.float64) / np.where(span > 0, span, 1.0), 0.0)
    w = np.clip(w, 0.0, 1.0)
    q = old_slerp(quat[i], quat[j], w)
    return np.where(q[:, 3:4] < 0, -q, q)


def old_observed_rotations(q_seq):
    """predictor.Predictor._run's rotation increments between observed orientations before the move to scipy."""
    return OldGeometry.quat_to_axis_angle(OldGeometry.quat_multiply(q_seq[1:], OldGeometry.quat_conjugate(q_seq[:-1])))


# ----------------------------------------------------------------------------------------------------- helpers
def unit(rng, shape):
    q = rng.normal(size=shape + (4,))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def assert_close(new, old, tol=TOL):
    new, old = np.asarray(new), np.asarray(old)
    assert new.shape == old.shape, (new.shape, old.shape)
    assert np.abs(new - old).max(initial=0.0) < tol, np.abs(new - old).max()


def assert_same_rotation(new, old, tol=TOL):
    """Quaternions equal up to sign, row by row."""
    new, old = np.asarray(new), np.asarray(old)
    assert new.shape == old.shape, (new.shape, old.shape)
    err = np.minimum(np.abs(new - old).max(-1), np.abs(new + old).max(-1))
    assert err.max(initial=0.0) < tol, err.max()


SHAPES = [(), (50,), (2, 5), (3, 1)]


# ------------------------------------------------------------------------------------------------------- tests
@pytest.mark.parametrize("shape", SHAPES)
def test_geometry_quaternion_helpers_equal_the_old_ones(shape):
    rng = np.random.default_rng(len(shape) * 7 + sum(shape))
    a, b = unit(rng, shape), unit(rng, shape)
    raw = rng.normal(size=shape + (4,)) * 3.0  # not unit
    v = rng.normal(size=shape + (3,))
    assert_close(geo.quat_normalize(raw), OldGeometry.quat_normalize(raw))
    assert_close(geo.quat_multiply(a, b), OldGeometry.quat_multiply(a, b))  # sign kept: the Hamilton product
    assert_close(geo.quat_conjugate(a), OldGeometry.quat_conjugate(a))
    assert_close(geo.quat_inverse(a), OldGeometry.quat_inverse(a))
    assert_close(geo.quat_rotate(a, v), OldGeometry.quat_rotate(a, v))
    assert_close(geo.quat_to_matrix(a), OldGeometry.quat_to_matrix(a))
    assert_close(geo.quat_to_matrix(a.astype(np.float32)), OldGeometry.quat_to_matrix(a.astype(np.float32)), 1e-6)
    m = OldGeometry.quat_to_matrix(a)
    assert_close(geo.matrix_to_quat(m), OldGeometry.matrix_to_quat(m))  # both w >= 0
    assert_close(geo.quat_to_axis_angle(a), OldGeometry.quat_to_axis_angle(a))
    assert_close(geo.quat_to_axis_angle(raw), OldGeometry.quat_to_axis_angle(raw))  # scale-free
    assert_close(geo.quat_angle_between(a, b), OldGeometry.quat_angle_between(a, b), 1e-8)
    for scale in (1e-9, 1e-4, 1.0, 3.0):  # tiny, small, beyond pi (w < 0 kept, as the old exponential map)
        rv = v * scale
        assert_close(geo.axis_angle_to_quat(rv), OldGeometry.axis_angle_to_quat(rv))
        assert_close(geo.axis_angle_to_matrix(rv), OldGeometry.axis_angle_to_matrix(rv))
    psi = rng.uniform(-7, 7, size=shape)
    assert_close(geo.yaw_quat(psi), OldGeometry.yaw_quat(psi))
    assert_close(geo.yaw_matrix(psi), OldGeometry.yaw_matrix(psi))


def test_geometry_broadcasts_as_before():
    rng = np.random.default_rng(3)
    a, b, v = unit(rng, (3, 1)), unit(rng, (3, 5)), rng.normal(size=(3, 5, 3))
    assert_close(geo.quat_multiply(a, b), OldGeometry.quat_multiply(a, b))
    assert_close(geo.quat_multiply(a[0, 0], b), OldGeometry.quat_multiply(a[0, 0], b))
    assert_close(geo.quat_rotate(a, v), OldGeometry.quat_rotate(a, v))
    assert_close(geo.quat_rotate(a[0, 0], v), OldGeometry.quat_rotate(a[0, 0], v))
    assert_close(geo.quat_angle_between(a, b), OldGeometry.quat_angle_between(a, b), 1e-8)
    psi = rng.uniform(-3, 3, size=(3, 5))
    # as in learn/baselines.analytic_sliding: (B, H) yaws times (B, 1) start orientations, float32 data
    q32 = a.astype(np.float32)
    assert_close(geo.quat_multiply(geo.yaw_quat(psi), q32), OldGeometry.quat_multiply(OldGeometry.yaw_quat(psi), q32),
                 1e-6)
    d, q0 = unit(rng, (4, 9)), unit(rng, (4,))
    assert_same_rotation(geo.quat_compose_scan(d, q0), OldGeometry.quat_compose_scan(d, q0))
    assert np.all(geo.quat_compose_scan(d, q0)[..., 3] >= 0)


def test_geometry_edge_cases():
    assert_close(geo.quat_to_axis_angle([0.0, 0.0, 0.0, 1.0]), np.zeros(3))
    assert_close(geo.axis_angle_to_quat(np.zeros((2, 3))), [[0, 0, 0, 1.0]] * 2)
    assert geo.quat_angle_between([0, 0, 0, 1.0], [0, 0, 0, -1.0]) < 1e-12  # q and -q: the same orientation
    rng = np.random.default_rng(4)
    a = unit(rng, (20,))
    assert geo.quat_angle_between(a, a).max() < 1e-12  # the old arccos formula gave up to ~4e-8 here
    assert geo.quat_to_axis_angle(np.zeros((0, 4))).shape == (0, 3)
    for bad in ([0.0, 0, 0, 0], [np.nan, 0, 0, 1], [np.inf, 0, 0, 1]):
        with pytest.raises(ValueError):
            geo.quat_normalize(bad)


def test_simulator_helpers_equal_the_old_ones():
    from physdyn_ros.sim import simulator as sim

    rng = np.random.default_rng(5)
    for _ in range(200):
        a, b = rng.normal(size=4), rng.normal(size=4)  # the simulator's helpers took non-unit quaternions too
        ua, ub = a / np.linalg.norm(a), b / np.linalg.norm(b)
        assert_close(sim.quat_to_matrix(a), OldSimulator.quat_to_matrix(a))
        assert_close(sim.tilt_angle(a), OldSimulator.tilt_angle(a), 1e-8)
        m = OldSimulator.quat_to_matrix(a)
        assert_same_rotation(geo.matrix_to_quat(m), OldSimulator.matrix_to_quat(m))
        assert_close(geo.quat_multiply(ua, geo.quat_conjugate(ub)),
                     OldSimulator.quat_mul(ua, OldSimulator.quat_conj(ub)))
        yaw = rng.uniform(-4, 4)
        assert_close(sim.yaw_quat(yaw), OldSimulator.yaw_quat(yaw))
    batch = rng.normal(size=(7, 4))
    assert_close(sim.tilt_angle(batch), OldSimulator.tilt_angle(batch), 1e-8)


def test_ros_convert_helpers_equal_the_old_ones():
    from physdyn_ros.ros import convert

    rng = np.random.default_rng(6)
    for _ in range(200):
        a, b = unit(rng, ()), unit(rng, ())
        assert_close(convert.quat_to_matrix(a), OldConvert.quat_to_matrix(a))
        assert_close(convert.quat_to_matrix(list(a)), OldConvert.quat_to_matrix(list(a)))
        assert abs(convert.quat_angle(a, b) - OldConvert.quat_angle(a, b)) < 1e-8
        assert abs(convert.quat_yaw(a) - OldConvert.quat_yaw(a)) < TOL
        assert convert.is_toppled(a) == OldConvert.is_toppled(a)
        yaw = rng.uniform(-4, 4)
        assert_close(convert.yaw_quaternion(yaw), OldConvert.yaw_quaternion(yaw))
    for angle in (math.pi / 4, math.pi / 4 - 1e-12, math.pi / 4 + 1e-12):  # the edge of toppling, bit for bit
        q = OldGeometry.axis_angle_to_quat(np.array([angle, 0.0, 0.0]))
        assert convert.is_toppled(q) == OldConvert.is_toppled(q)
        assert convert.is_toppled(q.astype(np.float32)) == OldConvert.is_toppled(q.astype(np.float32))
    assert convert.quat_angle([0, 0, 0, 1.0], [0, 0, 0, 1.0]) == 0.0
    assert isinstance(convert.quat_angle([0, 0, 0, 1.0], [0, 0, 1.0, 0]), float)


def test_bag_sampling_slerps_as_before():
    from physdyn_ros.bag.pushes import States, sample

    rng = np.random.default_rng(7)
    n = 40
    t = np.cumsum(rng.integers(1, 80_000_000, n)).astype(np.int64) + 1_700_000_000_000_000_000
    # a continuous (same-hemisphere) orientation sequence, as load_session stores it: small random turns
    quat = [unit(rng, ())]
    for _ in range(n - 1):
        step = geo.axis_angle_to_quat(rng.normal(size=3) * 0.4)
        q = OldGeometry.quat_multiply(step, quat[-1])
        quat.append(q if np.dot(q, quat[-1]) >= 0 else -q)
    quat = np.array(quat)
    quat[5] = quat[4]  # an exactly repeated orientation (the old slerp's small-angle branch)
    states = States(t=t, pos=rng.normal(size=(n, 3)), quat=quat, lin=None, ang=None, topic="s", msgtype="m")
    times = np.concatenate([rng.integers(t[0] - 10**8, t[-1] + 10**8, 300), t, [t[0], t[-1]]]).astype(np.int64)
    got = sample(states, times)
    assert_close(got["quat"], old_sample_quat(t, quat, times))
    assert np.all(got["quat"][:, 3] >= 0)
    one = States(t=t[:1], pos=states.pos[:1], quat=-quat[:1], lin=None, ang=None, topic="s", msgtype="m")
    assert_close(sample(one, times[:5])["quat"], old_sample_quat(t[:1], -quat[:1], times[:5]))


def test_bag_finite_difference_rotations_as_before():
    from physdyn_ros.bag.pushes import finite_difference_velocities

    rng = np.random.default_rng(8)
    quat = unit(rng, (30,))
    pos = rng.normal(size=(30, 3))
    _, ang = finite_difference_velocities(pos, quat, 0.1)
    lo = np.concatenate([[0], np.arange(28), [28]])
    hi = np.concatenate([[1], np.arange(2, 30), [29]])
    want = OldGeometry.quat_to_axis_angle(OldGeometry.quat_multiply(quat[hi], OldGeometry.quat_conjugate(quat[lo])))
    assert_close(ang, want / ((hi - lo) * 0.1)[:, None])


def test_predictor_rotations_equal_the_old_ones():
    from physdyn_ros import predictor
    from physdyn_ros.learn import frames

    rng = np.random.default_rng(9)
    q_seq = unit(rng, (12,))
    assert_close(predictor._rotation_increments(q_seq), old_observed_rotations(q_seq))
    # compose_rotations keeps a numpy kernel (the batch-1 hot path): its exponential map equals scipy's
    from scipy.spatial.transform import Rotation

    for scale in (1e-9, 1e-4, 0.3, 3.0):
        rv = rng.normal(size=(4, 7, 3)) * scale
        assert_close(frames._exp_map(rv), Rotation.from_rotvec(rv).as_quat())
    for b, h in ((1, 60), (3, 20), (40, 40)):
        q0, d_rot = unit(rng, (b,)), rng.normal(size=(b, h, 3)) * 0.3
        want = [q0]
        for t in range(h):
            want.append(OldGeometry.quat_multiply(OldGeometry.axis_angle_to_quat(d_rot[:, t]), want[-1]))
        want = np.stack(want, 1)
        want = np.where(want[..., 3:] < 0, -want, want)
        assert_close(predictor.compose_rotations(q0, d_rot), want)


def test_simulator_object_frame_equals_the_old_conversion():
    """Simulator.state() turns pybullet's inertial-frame orientation into the object frame as before."""
    from physdyn_ros.shapes import make_procedural
    from physdyn_ros.sim.simulator import SimConfig, Simulator

    sim = Simulator(SimConfig())
    try:
        sim.spawn(make_procedural("mug", 0))  # a mug's principal axes are not its object axes
        assert sim._q_inertial[3] < 0.9999
        q_in = OldSimulator.matrix_to_quat(OldSimulator.quat_to_matrix(sim._q_inertial))
        rng = np.random.default_rng(10)
        for q in unit(rng, (20,)):
            sim.set_pose(np.array([0.0, 0.0, 0.5]), q)
            _, q_wi = sim.client.getBasePositionAndOrientation(sim.body)
            assert_same_rotation(np.asarray(q_wi), OldSimulator.quat_mul(q, q_in), 1e-6)  # pybullet stores floats
            want = OldSimulator.quat_mul(np.asarray(q_wi), OldSimulator.quat_conj(q_in))
            want = want / np.linalg.norm(want)
            assert_close(sim.state()[1], -want if want[3] < 0 else want)
    finally:
        sim.close()
