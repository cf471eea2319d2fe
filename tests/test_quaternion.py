"""The shared quaternion helpers (imurig.kernel.quaternion) against closed forms: a rotation by angle a
about the unit axis n is q = (cos a/2, sin a/2 n) and turns v into Rodrigues' formula
v cos a + (n × v) sin a + n (n · v)(1 − cos a); products compose those rotations, conjugates undo them."""
from __future__ import annotations

import numpy as np

from imurig.kernel.quaternion import q_conj, q_mult, q_rotate

EPS = np.finfo(float).eps


def _axis_angle(rng, n):
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = rng.uniform(-np.pi, np.pi, n)
    q = np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axis], axis=1)
    return axis, angle, q


def _rodrigues(axis, angle, v):
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return v * c + np.cross(axis, v) * s + axis * np.sum(axis * v, axis=1, keepdims=True) * (1 - c)


def test_rotation_is_rodrigues_and_the_sandwich_product():
    rng = np.random.default_rng(7)
    axis, angle, q = _axis_angle(rng, 1000)
    v = rng.normal(size=(1000, 3))
    r = q_rotate(q, v)
    np.testing.assert_allclose(r, _rodrigues(axis, angle, v), rtol=0, atol=16 * EPS * np.abs(v).max())
    sandwich = q_mult(q_mult(q, np.concatenate([np.zeros((1000, 1)), v], axis=1)), q_conj(q))
    np.testing.assert_allclose(sandwich[:, 1:], r, rtol=0, atol=16 * EPS * np.abs(v).max())
    np.testing.assert_allclose(sandwich[:, 0], 0.0, rtol=0, atol=16 * EPS * np.abs(v).max())
    # one vector (3,) for many rotations, and the lengths kept
    one = q_rotate(q, v[0])
    np.testing.assert_allclose(one, _rodrigues(axis, angle, np.broadcast_to(v[0], v.shape)), rtol=0,
                               atol=16 * EPS * np.abs(v[0]).max())
    np.testing.assert_allclose(np.linalg.norm(r, axis=1), np.linalg.norm(v, axis=1), rtol=8 * EPS)


def test_products_compose_and_conjugates_undo():
    rng = np.random.default_rng(8)
    _, _, p = _axis_angle(rng, 500)
    _, _, q = _axis_angle(rng, 500)
    v = rng.normal(size=(500, 3))
    np.testing.assert_allclose(q_rotate(q_mult(p, q), v), q_rotate(p, q_rotate(q, v)), rtol=0, atol=32 * EPS * 3)
    np.testing.assert_allclose(q_rotate(q_conj(q), q_rotate(q, v)), v, rtol=0, atol=32 * EPS * 3)
    ident = q_mult(q, q_conj(q))
    np.testing.assert_allclose(ident, np.broadcast_to([1.0, 0, 0, 0], ident.shape), rtol=0, atol=8 * EPS)
