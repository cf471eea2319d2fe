"""Quaternion arithmetic shared by every layer: scalar-first unit quaternions (..., 4) = (w, x, y, z).

A unit quaternion q_AB rotates vectors from frame B into frame A, v_A = q_AB ⊗ (0, v_B) ⊗ q_AB*, and
composes as rotation matrices do: C(p ⊗ q) = C(p) C(q). The rigs' batched kinematics, the flights'
navigation frames, the scoring of a navigation solution and the .rrd's body poses all use these three.
"""
from __future__ import annotations

import numpy as np

__all__ = ["q_mult", "q_conj", "q_rotate"]


def q_mult(p, q) -> np.ndarray:
    """Hamilton product p ⊗ q of quaternions (..., 4) wxyz (composes rotations: C(p⊗q) = C(p)C(q))."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([pw * qw - px * qx - py * qy - pz * qz,
                     pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx,
                     pw * qz + px * qy - py * qx + pz * qw], axis=-1)


def q_conj(q) -> np.ndarray:
    """Conjugate (inverse of a unit quaternion), (..., 4) wxyz."""
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def q_rotate(q, v) -> np.ndarray:
    """v (3,) or (..., 3) rotated by the unit quaternions q (..., 4): q ⊗ (0, v) ⊗ q*, evaluated as
    v + 2 w (u × v) + 2 u × (u × v) with q = (w, u) (MuJoCo's ``mju_rotVecQuat``).

    Component by component on contiguous arrays (the products and differences of ``np.cross``, in its
    order: the same numbers, ~40 % less time than on the interleaved (..., 3) layout)."""
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    shape = np.broadcast_shapes(q.shape[:-1] + (3,), v.shape)
    w = np.broadcast_to(q[..., 0], shape[:-1])
    u0, u1, u2 = (np.ascontiguousarray(np.broadcast_to(q[..., i], shape[:-1])) for i in (1, 2, 3))
    vb = np.broadcast_to(v, shape)
    v0, v1, v2 = (np.ascontiguousarray(vb[..., i]) for i in range(3))
    t0, t1, t2 = 2 * (u1 * v2 - u2 * v1), 2 * (u2 * v0 - u0 * v2), 2 * (u0 * v1 - u1 * v0)   # 2 u × v
    out = np.empty(shape)
    out[..., 0] = v0 + w * t0 + (u1 * t2 - u2 * t1)
    out[..., 1] = v1 + w * t1 + (u2 * t0 - u0 * t2)
    out[..., 2] = v2 + w * t2 + (u0 * t1 - u1 * t0)
    return out
