"""The paper's 18-state filter between measurement updates, compiled with numba: the propagation
of :func:`imurig.flights.ekf_model.propagate` over a span of epochs in one call.

Between two updates (GPS, compass and temperatures at 1 Hz; 25 navigation epochs at 25 Hz) the
filter only propagates: per epoch the corrected increments, the INS step
(:func:`imurig.flights.navmath.nav_step`), F (:func:`imurig.flights.ekf_model._base_rows`) and

    Φ = I + F T + ½ (F T)²,   P ← Φ (P + ½ Q T) Φᵀ + ½ Q T     (Q diagonal)

and the record of the epoch (also with the receiver's Gauss-Markov error states: 21). Called from
Python that is ~60 µs per epoch, mostly the overhead of small numpy calls and float objects;
:func:`propagate_span` does the whole span in compiled code (~5 µs per epoch). The navigation
equations and F are *the same Python source* as the plain-float path, compiled by :func:`_compiled`
(one copy of the maths); only the span loop and the n × n products are written here. Results agree
with the Python path to rounding (matrix products summed in another order; tested).

Cost: numba + llvmlite (~210 MB installed), ~0.3 CPU-s to import numba, ~0.2 CPU-s to load the cached
machine code; on the first run after an install or an edit of the compiled functions ~4.5 CPU-s of
compilation, cached on disk next to the sources (``cache=True``). Loops are written element by
element (no slice assignments, no indexing of nested tuples): that halves the compilation. This
module is imported only when such a filter runs (:mod:`imurig.flights.ekf`), never at the CLI's
start-up.
"""
from __future__ import annotations

import math
import types
from pathlib import Path

import numba
import numpy as np
from imurig.flights import earth as E
from imurig.flights import ekf_model
from imurig.flights import navmath as nm

#: the float kernels of :mod:`imurig.flights.navmath` the compiled functions call
_NAVMATH_CALLS = ("rates", "dcm", "mat_vec", "cross", "qmul", "qrot", "qnormalised")


def _drop_stale_cache() -> None:
    """numba keys each function's cache on its own source file only, but the machine code of this
    module's functions also holds the navigation equations and F compiled from
    :mod:`imurig.flights.navmath` and :mod:`imurig.flights.ekf_model`: drop this module's cache
    when one of those files is newer (an edit there then recompiles here too)."""
    here = Path(__file__).parent
    newest = max((here / name).stat().st_mtime for name in ("navmath.py", "ekf_model.py"))
    for f in (here / "__pycache__").glob("ekf_kernel.*.nbi"):
        try:
            if f.stat().st_mtime < newest:
                f.unlink()
        except FileNotFoundError:      # another process dropped it first
            pass


_drop_stale_cache()


def _jit(fn):
    return numba.njit(cache=True, nogil=True)(fn)


def _compiled(fn, **globals_):
    """``fn`` (plain Python on floats and tuples) compiled by numba, with the global names it uses
    rebound to ``globals_`` (their compiled versions); the source stays the one definition."""
    g = dict(fn.__globals__)
    g.update(globals_)
    f = types.FunctionType(fn.__code__, g, fn.__name__, fn.__defaults__, fn.__closure__)
    f.__qualname__, f.__module__, f.__doc__ = fn.__qualname__, fn.__module__, fn.__doc__
    return _jit(f)


_nm = types.ModuleType("imurig.flights.navmath_compiled", "compiled navmath float kernels")
for _name in _NAVMATH_CALLS:
    setattr(_nm, _name, _jit(getattr(nm, _name)))
_nav_step = _compiled(nm.nav_step, **{n: getattr(_nm, n) for n in _NAVMATH_CALLS})
_base_rows = _compiled(ekf_model._base_rows, nm=_nm, E=E)


@_jit
def _covariance_step(P, F, qc, T, FT, Phi, tmp):
    """P ← Φ (P + ½ Q T) Φᵀ + ½ Q T with Φ = I + F T + ½ (F T)² (in place; FT, Phi, tmp scratch).
    Φ is sparse (of the 18 states' rows, nine are e_iᵀ and the rest ~15 nonzeros), so the products
    run over each row's nonzero entries."""
    n = P.shape[0]
    for i in range(n):
        for j in range(n):
            FT[i, j] = F[i, j] * T
    nz = np.empty((n, n), np.int64)           # the columns of row i's nonzero entries: nz[i, :cnt[i]]
    cnt = np.zeros(n, np.int64)
    for i in range(n):                        # Φ = ½ (F T)(F T) + F T + I
        for j in range(n):
            Phi[i, j] = 0.0
        for m in range(n):
            a = FT[i, m]
            if a != 0.0:
                for j in range(n):
                    Phi[i, j] += a * FT[m, j]
        for j in range(n):
            Phi[i, j] = Phi[i, j] * 0.5 + FT[i, j]
        Phi[i, i] += 1.0
        for j in range(n):
            if Phi[i, j] != 0.0:
                nz[i, cnt[i]] = j
                cnt[i] += 1
    for i in range(n):
        P[i, i] += qc[i] * (0.5 * T)
    for i in range(n):                        # tmp = Φ P
        for j in range(n):
            tmp[i, j] = 0.0
        for c in range(cnt[i]):
            m = nz[i, c]
            a = Phi[i, m]
            for j in range(n):
                tmp[i, j] += a * P[m, j]
    for i in range(n):                        # P = tmp Φᵀ
        for j in range(n):
            s = 0.0
            for c in range(cnt[j]):
                m = nz[j, c]
                s += tmp[i, m] * Phi[j, m]
            P[i, j] = s
    for i in range(n):
        P[i, i] += qc[i] * (0.5 * T)


@_jit
def _corrected(x, b, s, T):
    """(x − b T)(1 − s) per axis, a 3-tuple (the corrections of ``ekf_model._corrected_increments``)."""
    return ((x[0] - b[0] * T) * (1.0 - s[0]), (x[1] - b[1] * T) * (1.0 - s[1]), (x[2] - b[2] * T) * (1.0 - s[2]))


@_jit
def propagate_span(k0, k1, C0, nav, P, F, qc, T, corr, kT, dtheta, dv, f_B, work, rec_nav, rec_Pd, rec_Pn):
    """Propagate from epoch ``k0`` to ``k1`` (> k0), recording the epochs k0+1 .. k1−1.

    ``C0`` (9,) C_NB the step from k0 linearises at (row-major; later steps use the current attitude);
    ``nav`` (10,) [lat, lon, h, v_N (3), q_NB (4)] in/out; ``P`` (n, n) in/out; ``F`` (n, n) with its
    constant entries (rows δv̇, ψ̇ of the 18 base states rewritten); ``qc`` (n,) the diagonal of Q;
    ``corr`` (4, 3) the corrections (b̂_g, ŝ_g, ŝ_a, b̂_a + k_T (T̂_a − T_ref)); ``kT`` (3,); the epoch
    data ``dtheta``, ``dv`` (M, 3), ``f_B`` (M+1, 3); ``work`` (3, n, n) scratch; the record ``rec_nav`` (M+1, 10),
    ``rec_Pd`` (M+1, n), ``rec_Pn`` (M+1, 9, 9). Same operations as
    :func:`imurig.flights.ekf_model.propagate` (n = 18, or 21 with the receiver's error)."""
    n = P.shape[0]
    C = (C0[0], C0[1], C0[2], C0[3], C0[4], C0[5], C0[6], C0[7], C0[8])
    kt = (kT[0], kT[1], kT[2])
    for k in range(k0, k1):
        if k > k0:                                       # the record of epoch k, and its attitude
            for i in range(10):
                rec_nav[k, i] = nav[i]
            for i in range(n):
                rec_Pd[k, i] = P[i, i]
            for i in range(9):
                for j in range(9):
                    rec_Pn[k, i, j] = P[i, j]
            C = _nm.dcm((nav[6], nav[7], nav[8], nav[9]))
        dth = _corrected(dtheta[k], corr[0], corr[1], T)       # (Δθ − b̂_g T)(1 − ŝ_g)
        dvc = _corrected(dv[k], corr[3], corr[2], T)           # (Δv − f̂_corr T)(1 − ŝ_a)
        f_in = _corrected(f_B[k], corr[3], corr[2], 1.0)       # (f − f̂_corr)(1 − ŝ_a)
        lat, lon, h = nav[0], nav[1], nav[2]
        v = (nav[3], nav[4], nav[5])
        r0 = _nm.rates(lat, h, v[0], v[1])
        rows = np.array(_base_rows(lat, h, v, f_in, C, kt, r0))
        for i in range(6):
            for j in range(18):
                F[3 + i, j] = rows[i, j]
        lat, lon, h, v1, q1 = _nav_step(lat, lon, h, v, (nav[6], nav[7], nav[8], nav[9]), dth, dvc, T, r0)
        nav[0], nav[1], nav[2] = lat, lon, h
        nav[3], nav[4], nav[5] = v1
        nav[6], nav[7], nav[8], nav[9] = q1
        _covariance_step(P, F, qc, T, work[0], work[1], work[2])


class SpanPropagator:
    """:func:`propagate_span` on a run's :class:`imurig.flights.ekf_state.FilterState` ``st``, epoch
    data ``ep`` and record ``rec``: :meth:`run` takes the filter from epoch k to k1. For the 18 base
    states, optionally with the receiver's Gauss-Markov position error (``st.compilable``)."""

    def __init__(self, st, ep, rec):
        if not st.compilable:
            raise ValueError(f"the compiled propagation does not cover these states: {st.cfg.state_names()}")
        n = st.lay.n
        self.st, self.T, self.rec = st, float(ep.T), rec
        self.data = tuple(np.ascontiguousarray(a, dtype=float) for a in (ep.dtheta_B, ep.dv_B, ep.f_B))
        self.work = np.empty((3, n, n))
        self.nav = np.empty(10)
        self.phi_gps = None if st.lay.G is None else math.exp(-self.T / st.cfg.gps_pos_tau_s)

    def run(self, k: int, k1: int, C) -> None:
        """From epoch k (recorded, updates done; ``C`` the 9-tuple C_NB to linearise at) to k1 > k,
        recording k+1 .. k1−1 and leaving ``st.x`` and ``st.P`` at k1."""
        st, x, nav = self.st, self.st.x, self.nav
        nav[0], nav[1], nav[2] = x.lat_rad, x.lon_rad, x.h_m
        nav[3:6], nav[6:10] = x.v_N, x.q_NB
        corr = np.array(st.corrections(), dtype=float)
        propagate_span(k, k1, np.array(C, dtype=float), nav, st.P, st.dynamics.F, np.asarray(st.qc, float), self.T,
                       corr, st.dynamics.kT, *self.data, self.work, self.rec.nav, self.rec.P_diag, self.rec.P_nav)
        lat, lon, h, *vq = nav.tolist()
        st.x = type(x)(lat, lon, h, np.array(vq[:3]), np.array(vq[3:]))
        if self.phi_gps is not None:            # the receiver's error estimate decays (as propagate does)
            for _ in range(k1 - k):
                st.bgps = st.bgps * self.phi_gps

