"""A cluster-robust t test for one coefficient with a small-sample correction (CR2, Bell-McCaffrey).

Model (whatever space the caller works in, e.g. whitened and with cluster-local nuisance columns
already projected out): y = B beta + e, B (N, k), the coefficient tested the last column's; the
rows fall in G clusters and errors of different clusters are independent. The least-squares
estimate's influence vector is a = B (B'B)^-1 e_k, so beta_k - beta_k,true = a'e.

The usual sandwich (CR1) sums the clusters' scores (a_g' r_g)^2 of the residuals r: residuals
are shrunk by the leverage H_gg of their own cluster, and with a few clusters that carry most of
the information (moves of different length and rate) CR1 is biased low and its t(G - 1) reference
too wide in its tails (Bell & McCaffrey 2002; Imbens & Kolesar 2016; Cameron & Miller 2015, VI).
CR2 undoes the shrinking: with A_g = (I - H_gg)^(-1/2),

    V_CR2 = sum_g (a_g' A_g r_g)^2,

unbiased when the errors are independent with equal variance (the working model), and the
reference is Student's t with the Bell-McCaffrey degrees of freedom: V_CR2 = e' M W W' M e with
W = [A_g a_g (zero outside cluster g)] and M = I - H, so V_CR2 / E V_CR2 is a weighted sum of
chi^2(1) with weights lambda, the eigenvalues of W' M W (G, G), approximated by a scaled chi^2
of (sum lambda)^2 / sum lambda^2 degrees of freedom.

Cluster-local nuisance columns the caller projected out (a level per cluster) belong to H as
well; their projector is zero on the residuals and on a's rows, so (I - H_gg)^(-1/2) acts on
them as (I - K_g K_g')^(-1/2) with K_g = B_g (B'B)^(-1/2) (exact; module test against the explicit
hat matrix).
"""
from __future__ import annotations

import numpy as np
import scipy.stats

#: leverages of a cluster at or above this are clamped (a cluster the fit passes through)
MAX_LEVERAGE = 1.0 - 1e-9


def cr2_test(B: np.ndarray, r: np.ndarray, cluster: np.ndarray) -> dict:
    """CR2 standard error of the last column's coefficient and its Bell-McCaffrey degrees of
    freedom (module doc). ``B`` (N, k) the regressors (orthogonal to any absorbed cluster-local
    columns; one with a norm below 1e-9 of the largest is dropped), ``r`` (N,) the least-squares residuals, ``cluster`` (N,) integer labels. Returns
    se, se_cr1 (the plain sandwich with the G / (G - 1) factor), dof and the number of clusters."""
    B = np.asarray(B, float)
    r = np.asarray(r, float)
    cluster = np.asarray(cluster)
    norm = np.linalg.norm(B, axis=0)
    keep = norm > 1e-9 * max(float(norm.max()), 1e-300)       # a column the data never excite is dropped
    keep[-1] = True
    Bn = B[:, keep] / norm[keep]
    # (B'B)^(-1/2) of the unit columns by eigen-decomposition (the fit's numerically null directions dropped)
    w, V = np.linalg.eigh(Bn.T @ Bn)
    ok = w > 1e-12 * w.max()
    Sinv_half = (V[:, ok] / np.sqrt(w[ok])) @ V[:, ok].T
    BtB_inv = (V[:, ok] / w[ok]) @ V[:, ok].T
    a = Bn @ BtB_inv[:, -1] / norm[-1]               # influence of the last coefficient
    labels, inv = np.unique(cluster, return_inverse=True)
    G = labels.size
    K = Bn @ Sinv_half
    score2, score1 = 0.0, 0.0
    C = np.zeros((Bn.shape[1], G))
    norms2 = np.zeros(G)
    for g in range(G):
        rows = np.flatnonzero(inv == g)
        U, s, _ = np.linalg.svd(K[rows], full_matrices=False)
        s2 = np.minimum(s ** 2, MAX_LEVERAGE)
        f = 1.0 / np.sqrt(1.0 - s2) - 1.0

        def A(x, U=U, f=f):
            return x + U @ (f * (U.T @ x))
        ag = a[rows]
        wg = A(ag)
        score2 += float(wg @ r[rows]) ** 2
        score1 += float(ag @ r[rows]) ** 2
        C[:, g] = Bn[rows].T @ wg
        norms2[g] = wg @ wg
    # W' M W = diag(|w_g|^2) - C' (B'B)^-1 C (M = I - H; the absorbed columns' projector is zero on W)
    WMW = np.diag(norms2) - C.T @ BtB_inv @ C
    lam = np.clip(np.linalg.eigvalsh(WMW), 0.0, None)
    dof = float(lam.sum() ** 2 / max(np.sum(lam ** 2), 1e-300))
    return {"se": float(np.sqrt(score2)), "se_cr1": float(np.sqrt(G / max(G - 1, 1) * score1)),
            "dof": dof, "clusters": int(G)}


def two_sided_p(t: float, dof: float) -> float:
    """Two-sided p-value of ``t`` against Student's t(``dof``)."""
    return float(2 * scipy.stats.t.sf(abs(t), dof))
