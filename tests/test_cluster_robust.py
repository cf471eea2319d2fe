"""The cluster-robust t test with the CR2 correction and Bell-McCaffrey degrees of freedom
(imurig.diagnose.cluster_robust), against its closed forms and by its level.

- The projected computation (cluster-local nuisance columns absorbed by the caller) equals the
  textbook one with the full hat matrix H: A_g = (I - H_gg)^(-1/2) (pseudo-inverse square root),
  V = sum_g (a_g' A_g r_g)^2, dof = (sum lambda)^2 / sum lambda^2 with lambda the eigenvalues of
  W' (I - H) W.
- One row per cluster and no absorbed columns: CR2 is HC2, sum a_i^2 r_i^2 / (1 - h_ii).
- Level: a design in which one cluster of twelve carries the slope's information. The plain
  sandwich against t(G - 1) rejects a true null far above alpha (Cameron & Miller 2015, VI); CR2
  against t(dof) must not (bounds: alpha +- 3 binomial SE of the simulated rate).
"""
from __future__ import annotations

import numpy as np

from imurig.diagnose.cluster_robust import cr2_test, two_sided_p


def _explicit(full: np.ndarray, y: np.ndarray, cluster: np.ndarray):
    """CR2 SE and Bell-McCaffrey dof of the last coefficient from the full hat matrix."""
    N = y.size
    P = np.linalg.pinv(full)
    H = full @ P
    M = np.eye(N) - H
    r, a = M @ y, P[-1]
    G = int(cluster.max()) + 1
    W, V = np.zeros((N, G)), 0.0
    for g in range(G):
        rows = np.flatnonzero(cluster == g)
        ev, U = np.linalg.eigh(np.eye(rows.size) - H[np.ix_(rows, rows)])
        ok = ev > 1e-10
        A = (U[:, ok] / np.sqrt(ev[ok])) @ U[:, ok].T
        W[rows, g] = A @ a[rows]
        V += float(W[rows, g] @ r[rows]) ** 2
    lam = np.clip(np.linalg.eigvalsh(W.T @ M @ W), 0, None)
    return np.sqrt(V), lam.sum() ** 2 / np.sum(lam ** 2), r


def test_projected_cr2_equals_the_explicit_hat_matrix_form():
    rng = np.random.default_rng(3)
    sizes = rng.integers(4, 12, 7)
    cl = np.repeat(np.arange(7), sizes)
    N = cl.size
    O = np.zeros((N, 14))                   # a level and a curve per cluster, absorbed by the caller
    for g in range(7):
        rows = cl == g
        O[rows, 2 * g], O[rows, 2 * g + 1] = 1.0, np.linspace(0, 1, rows.sum()) ** 2
    X = rng.standard_normal((N, 3)) * np.array([1.0, 3.0, 0.2])
    y = rng.standard_normal(N)
    se, dof, r = _explicit(np.hstack([O, X]), y, cl)
    out = cr2_test(X - O @ np.linalg.lstsq(O, X, rcond=None)[0], r, cl)
    assert np.isclose(out["se"], se, rtol=1e-10) and np.isclose(out["dof"], dof, rtol=1e-10)
    assert out["clusters"] == 7


def test_one_row_per_cluster_is_hc2():
    rng = np.random.default_rng(4)
    B = np.column_stack([np.ones(30), rng.standard_normal(30) ** 3])
    y = rng.standard_normal(30)
    P = np.linalg.pinv(B)
    h = np.einsum("ij,ji->i", B, P)
    r = y - B @ (P @ y)
    hc2 = np.sqrt(np.sum(P[-1] ** 2 * r ** 2 / (1 - h)))
    assert np.isclose(cr2_test(B, r, np.arange(30))["se"], hc2, rtol=1e-10)


def test_cr2_keeps_the_level_where_the_plain_sandwich_does_not():
    rng = np.random.default_rng(0)
    G, n, alpha, sims = 12, 6, 0.05, 600
    cl = np.repeat(np.arange(G), n)
    x = np.concatenate([6.0 * rng.standard_normal(n), 0.5 * rng.standard_normal((G - 1) * n)])
    B = np.column_stack([np.ones(G * n), x])
    Q, _ = np.linalg.qr(B)
    P = np.linalg.pinv(B)
    rej_cr1 = rej_cr2 = 0
    for _ in range(sims):
        y = rng.standard_normal(G * n)           # the slope is 0
        r = y - Q @ (Q.T @ y)
        beta = float(P[-1] @ y)
        o = cr2_test(B, r, cl)
        rej_cr2 += two_sided_p(beta / o["se"], o["dof"]) < alpha
        rej_cr1 += two_sided_p(beta / o["se_cr1"], G - 1) < alpha
    bound = 3 * np.sqrt(alpha * (1 - alpha) / sims)
    assert rej_cr2 / sims <= alpha + bound
    assert rej_cr1 / sims > alpha + bound          # the design does show the plain sandwich's failure
