"""Cramér-Rao lower bound of a Gaussian measurement model (Fisher information J' C^-1 J).

For observations y = h(p) + e, e ~ N(0, C), the Fisher information at the true p is

    F = J' C^-1 J,           J = dh/dp at the truth       [(m, P) Jacobian, C (m, m)]

and any unbiased estimator has cov(p_hat) >= F^-1 (the Cramér-Rao lower bound). Nuisance
parameters (e.g. table errors the lab surveys) are part of p; observing them directly
with variance s^2 (the survey) adds 1/s^2 to their diagonal of F. The bound of the
parameters of interest is their block of F^-1 (not the inverse of their block of F,
which would pretend the nuisance parameters were known).

When C is not Gaussian but has the given second moments, F^-1 is the covariance of the
best linear unbiased estimator (Gauss-Markov) of the linearised model: the yardstick for
any least-squares calibration.
"""
from __future__ import annotations

import numpy as np

from imurig.kernel.errors import UnidentifiableTermsError


def fisher_information(J: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Fisher information of blocks of observations.

    J : (n, k, P) Jacobian of n independent blocks of k observations each.
    C : (n, k, k) covariance of each block (or (k, k) shared).
    Returns F (P, P) = sum_n J_n' C_n^-1 J_n.
    """
    J = np.asarray(J, float)
    C = np.broadcast_to(np.asarray(C, float), (J.shape[0], J.shape[1], J.shape[1]))
    L = np.linalg.cholesky(C)                                   # C = L L'
    W = np.linalg.solve(L, J)                                   # L^-1 J, (n, k, P)
    return np.einsum("nka,nkb->ab", W, W)


def crlb_covariance(F: np.ndarray, n_interest: int | None = None, names=None) -> np.ndarray:
    """Inverse Fisher information (the CRLB covariance), its leading ``n_interest`` block.

    The columns are scaled to unit diagonal before inversion (parameters of very different
    magnitude, e.g. 0.1 V/(m/s^2) against 1e-6 1/(m/s^2)); a singular F (a parameter the
    design does not excite) raises :class:`UnidentifiableTermsError`.
    """
    F = 0.5 * (F + F.T)
    d = np.sqrt(np.clip(np.diag(F), 0, None))
    if np.any(d == 0):
        bad = [names[i] if names else i for i in np.flatnonzero(d == 0)]
        raise UnidentifiableTermsError(f"the design carries no information on {bad}: the Cramér-Rao bound is "
                                       "infinite; add positions that excite these parameters", [str(b) for b in bad])
    Fs = F / np.outer(d, d)
    w, V = np.linalg.eigh(Fs)
    if w[0] <= w[-1] * 1e-14:
        raise UnidentifiableTermsError("the Fisher information is singular (parameters not separable by this "
                                       "design); the Cramér-Rao bound is infinite", list(names or []))
    cov = (V / w) @ V.T / np.outer(d, d)
    k = cov.shape[0] if n_interest is None else n_interest
    return cov[:k, :k]


def numerical_jacobian(h, p: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Central-difference Jacobian of h: (P,) -> array (...), returned as (..., P)."""
    p = np.asarray(p, float)
    cols = []
    for i in range(p.size):
        e = np.zeros_like(p)
        e[i] = step[i]
        cols.append((h(p + e) - h(p - e)) / (2 * step[i]))
    return np.stack(cols, axis=-1)
