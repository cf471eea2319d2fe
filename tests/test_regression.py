"""Truth-based tests of imurig.calibration.{terms, regression, stepwise}.

Every test compares against an independent truth: published numbers (seed
Table 4.1 / eq. 4.17), closed-form formulas evaluated here with plain numpy,
the known generating model, or the sampling distribution of a Monte-Carlo.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from imurig.calibration.regression import check_identifiable, fit_ols
from imurig.calibration.stepwise import backward_elimination, forward_selection
from imurig.calibration.terms import Term, TermLibrary, polynomial, seed_accelerometer_terms
from imurig.kernel.errors import UnidentifiableTermsError

SWIMMER_CSV = Path(__file__).resolve().parents[2] / "shared" / "reference" / "swimmer_table_4_1.csv"  # ../shared
EPS = np.finfo(np.float64).eps


def _load_swimmer() -> tuple[np.ndarray, np.ndarray]:
    lines = [ln for ln in SWIMMER_CSV.read_text().splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    assert lines[0].split(",") == ["distance_m", "time_s"]
    data = np.loadtxt(lines[1:], delimiter=",")
    return data[:, 0], data[:, 1]


def _well_conditioned_problem(rng: np.random.Generator, n: int = 40):
    x1, x2 = rng.uniform(-1.0, 1.0, size=(2, n))
    X = np.column_stack([np.ones(n), x1, x2, x1 * x2])
    b = np.array([0.7, -1.3, 2.1, 0.4])
    return X, b


# ---------------------------------------------------------------------------
# published reference


@pytest.mark.skipif(not SWIMMER_CSV.exists(), reason="seed reference data not available")
def test_swimmer_line_matches_seed_eq_4_17():
    x, y = _load_swimmer()
    assert x.size == 21
    res = fit_ols(np.column_stack([np.ones_like(x), x]), y, ["1", "distance"])
    assert round(res.coef("1"), 4) == 11.2166
    assert round(res.coef("distance"), 4) == 0.3958


# ---------------------------------------------------------------------------
# closed forms


def test_exact_data_recovers_coefficients():
    rng = np.random.default_rng(1)
    X, b = _well_conditioned_problem(rng)
    res = fit_ols(X, X @ b, ["1", "a", "b", "a*b"])
    np.testing.assert_allclose(res.coef_, b, rtol=1e-10, atol=0)
    assert res.ss_res < 1e-25
    assert res.r2 == pytest.approx(1.0, abs=1e-12)


def test_statistics_match_textbook_formulas():
    rng = np.random.default_rng(2)
    X, b = _well_conditioned_problem(rng)
    n, p = X.shape
    y = X @ b + rng.normal(0.0, 0.3, n)
    res = fit_ols(X, y, ["1", "a", "b", "a*b"])

    # independent reference: normal equations with an explicit inverse (fine: cond ~ 3)
    XtX_inv = np.linalg.inv(X.T @ X)
    b_ref = XtX_inv @ X.T @ y
    e = y - X @ b_ref
    ss_res = e @ e                                    # eq. 4.25
    assert ss_res == pytest.approx(y @ y - b_ref @ X.T @ y, rel=1e-9)  # eq. 4.26
    ms_res = ss_res / (n - p)                         # eq. 4.27
    ss_t = y @ y - y.sum() ** 2 / n                   # eq. 4.28
    r2 = 1 - ss_res / ss_t                            # eq. 4.29
    r2_adj = 1 - (ss_res / (n - p)) / (ss_t / (n - 1))  # eq. 4.30
    se = np.sqrt(ms_res * np.diag(XtX_inv))
    loglik = -n / 2 * (np.log(2 * np.pi * ss_res / n) + 1)

    np.testing.assert_allclose(res.coef_, b_ref, rtol=1e-10)
    np.testing.assert_allclose(res.residuals_, e, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(res.fitted_, X @ b_ref, rtol=1e-10)
    assert (res.n, res.p, res.dof) == (n, p, n - p)
    assert res.ss_res == pytest.approx(ss_res, rel=1e-10)
    assert res.ms_res == pytest.approx(ms_res, rel=1e-10)
    assert res.ss_t == pytest.approx(ss_t, rel=1e-10)
    assert res.r2 == pytest.approx(r2, rel=1e-10)
    assert res.r2_adj == pytest.approx(r2_adj, rel=1e-10)
    assert res.R == pytest.approx(math.sqrt(r2), rel=1e-10)          # seed appendix C "R"
    assert res.R_adj == pytest.approx(math.sqrt(r2_adj), rel=1e-10)  # seed appendix C "Radj"
    np.testing.assert_allclose(res.std_error_, se, rtol=1e-9)
    np.testing.assert_allclose(res.cov_, ms_res * XtX_inv, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(res.t_value_, b_ref / se, rtol=1e-9)
    assert res.sigma_res == pytest.approx(np.std(e, ddof=1), rel=1e-10)
    assert res.aic == pytest.approx(-2 * loglik + 2 * p, rel=1e-10)
    assert res.bic == pytest.approx(-2 * loglik + p * np.log(n), rel=1e-10)
    assert res.std_error("a") == pytest.approx(se[1], rel=1e-9)
    assert res.condition_number >= 1.0
    np.testing.assert_allclose(res.predict(X[:3]), X[:3] @ b_ref, rtol=1e-10)

    rows = res.table()
    assert [r["name"] for r in rows] == ["1", "a", "b", "a*b"]
    assert rows[2]["estimate"] == pytest.approx(b_ref[2], rel=1e-10)
    d = json.loads(json.dumps(res.to_dict(include_residuals=True), allow_nan=False))
    assert d["coef"] == pytest.approx(list(b_ref), rel=1e-10) and len(d["residuals"]) == n


def test_weighted_statistics_match_closed_form():
    rng = np.random.default_rng(3)
    X, b = _well_conditioned_problem(rng, n=60)
    n, p = X.shape
    sigma = rng.uniform(0.1, 1.0, n)
    w = 1.0 / sigma**2
    y = X @ b + sigma * rng.normal(size=n)
    res = fit_ols(X, y, ["1", "a", "b", "a*b"], weights=w)
    W = np.diag(w)
    A_inv = np.linalg.inv(X.T @ W @ X)
    b_ref = A_inv @ X.T @ W @ y
    e = y - X @ b_ref
    ss_res = e @ W @ e
    ybar = np.sum(w * y) / np.sum(w)
    ss_t = np.sum(w * (y - ybar) ** 2)
    np.testing.assert_allclose(res.coef_, b_ref, rtol=1e-10)
    assert res.ss_res == pytest.approx(ss_res, rel=1e-10)
    assert res.ss_t == pytest.approx(ss_t, rel=1e-10)
    assert res.r2 == pytest.approx(1 - ss_res / ss_t, rel=1e-10)
    np.testing.assert_allclose(res.std_error_, np.sqrt(ss_res / (n - p) * np.diag(A_inv)), rtol=1e-9)
    # scaling all weights by a constant changes nothing but the likelihood constant
    res2 = fit_ols(X, y, ["1", "a", "b", "a*b"], weights=7.0 * w)
    np.testing.assert_allclose(res2.coef_, res.coef_, rtol=1e-12)
    np.testing.assert_allclose(res2.std_error_, res.std_error_, rtol=1e-12)


def test_ill_conditioned_design_is_solved_without_normal_equations():
    # Vandermonde in t on [0, 1] up to t^9: cond(X) ~ 1e7, so forming X'X
    # (cond ~ 1e14) loses ~all digits while a QR solution keeps ~cond*eps.
    t = np.linspace(0.0, 1.0, 200)
    X = np.vander(t, 10, increasing=True)
    b = np.linspace(1.0, -1.0, 10)
    kappa = np.linalg.cond(X)
    assert kappa > 1e6
    res = fit_ols(X, X @ b, [f"t^{k}" for k in range(10)])
    err = np.linalg.norm(res.coef_ - b) / np.linalg.norm(b)
    assert err < 100 * kappa * EPS
    normal_eq = np.linalg.solve(X.T @ X, X.T @ (X @ b))
    assert np.linalg.norm(normal_eq - b) / np.linalg.norm(b) > 100 * err  # the test can tell the two apart


# ---------------------------------------------------------------------------
# Monte-Carlo: standard errors describe the actual scatter of the estimates


@pytest.mark.parametrize("weighted", [False, True])
def test_standard_errors_match_monte_carlo_scatter(weighted: bool):
    rng = np.random.default_rng(20240607)
    n, reps = 12, 2000  # small n - p = 8: a wrong dof (n instead of n - p) is a 22 % error
    x = np.linspace(-1.0, 1.0, n)
    X = np.column_stack([np.ones(n), x, x**2, np.sin(3 * x)])
    b = np.array([1.0, 0.5, -2.0, 0.3])
    sigma = 0.2 * (1.0 + 2.0 * (x > 0)) if weighted else np.full(n, 0.2)
    w = 1.0 / sigma**2 if weighted else None
    names = ["1", "x", "x^2", "s"]
    coefs = np.empty((reps, 4))
    se2 = np.empty((reps, 4))
    noise = rng.normal(size=(reps, n)) * sigma
    for r in range(reps):
        res = fit_ols(X, X @ b + noise[r], names, weights=w)
        coefs[r] = res.coef_
        se2[r] = res.std_error_**2
    emp_std = coefs.std(axis=0, ddof=1)
    rms_se = np.sqrt(se2.mean(axis=0))  # E[se^2] is the exact variance (ms_res unbiased)
    # relative sampling std of emp_std ~ 1/sqrt(2 (R - 1)); of rms_se ~ sqrt(2/(n-p)) / (2 sqrt(R))
    rel_sd = math.hypot(1 / math.sqrt(2 * (reps - 1)), math.sqrt(2 / (n - 4)) / (2 * math.sqrt(reps)))
    np.testing.assert_array_less(np.abs(emp_std / rms_se - 1), 4 * rel_sd)
    # and both agree with the analytic standard deviation sigma * sqrt(diag((X'WX)^-1))
    Wt = np.diag(1 / sigma**2)
    true_sd = np.sqrt(np.diag(np.linalg.inv(X.T @ Wt @ X)))
    np.testing.assert_array_less(np.abs(emp_std / true_sd - 1), 4 / math.sqrt(2 * (reps - 1)))
    np.testing.assert_array_less(np.abs(coefs.mean(axis=0) - b) / true_sd, 4 / math.sqrt(reps))


def test_gls_with_known_and_reml_white_variance_is_honest():
    """Errors with a known part K (heteroscedastic diagonal + a low-rank survey-like term) and an
    unknown white part s^2: REML recovers s^2, and the known-covariance GLS standard errors match
    the estimates' scatter: sum of z^2 over the replicates inside its chi-square 99 % interval."""
    from scipy.stats import chi2

    from imurig.calibration.regression import fit_gls
    from imurig.calibration.gls import white_variance_reml

    rng = np.random.default_rng(7)
    n, reps = 80, 200
    x = np.linspace(0, np.pi, n)
    X = np.column_stack([np.ones(n), np.cos(x), np.sin(x), np.cos(x) ** 2])
    b = np.array([0.1, 1.0, -0.5, 2e-3])
    D = 4e-8 * np.sin(2 * x) ** 2                    # zero where the "setting error" has no effect
    J = np.column_stack([np.sin(x), np.cos(x)]) * 2e-4  # survey: two parameters, 1 sigma each
    K = np.diag(D) + J @ J.T
    s2 = 0.02 * D.mean()
    L = np.linalg.cholesky(K + s2 * np.eye(n))
    names = ["1", "c", "s", "c2"]
    z = np.empty((reps, 4))
    s2_hat = np.empty(reps)
    for r in range(reps):
        y = X @ b + L @ rng.standard_normal(n)
        s2_hat[r] = white_variance_reml(X, y, K)
        res = fit_gls(X, y, names, K + s2_hat[r] * np.eye(n), known_cov=True)
        z[r] = (res.coef_ - b) / res.std_error_
    assert abs(np.mean(s2_hat) / s2 - 1) < 0.1  # REML: unbiased to O(p/n); its own scatter is ~2 %
    lo, hi = chi2.ppf([0.005, 0.995], reps)
    for k in range(4):
        assert lo < np.sum(z[:, k] ** 2) < hi, (names[k], np.sum(z[:, k] ** 2), lo, hi)


# ---------------------------------------------------------------------------
# rank deficiency and input validation


def test_rank_deficiency_names_exactly_the_dependent_terms():
    rng = np.random.default_rng(4)
    ax, ay = rng.normal(size=(2, 50))
    inputs = {"ax": ax, "ay": ay, "az": 2.0 * ax}
    lib = polynomial(["ax", "ay", "az"], 1)
    X = lib.design(inputs)
    with pytest.raises(UnidentifiableTermsError) as exc:
        fit_ols(X, ay + rng.normal(size=50), lib.names)
    assert sorted(exc.value.terms) == ["ax", "az"]
    msg = str(exc.value)
    assert "{ax, az}" in msg and "az = 2*ax" in msg and "ay" not in msg
    assert "add" in msg and "drop" in msg  # says how to fix it


def test_rank_deficiency_duplicated_column_and_two_groups():
    rng = np.random.default_rng(5)
    Z = rng.normal(size=(30, 4))
    X = np.column_stack([Z[:, 0], Z[:, 1], Z[:, 1], Z[:, 2], Z[:, 3], Z[:, 0] - 3 * Z[:, 3]])
    names = ["a", "b", "b_copy", "c", "d", "e"]
    with pytest.raises(UnidentifiableTermsError) as exc:
        fit_ols(X, rng.normal(size=30), names)
    assert sorted(exc.value.terms) == ["a", "b", "b_copy", "d", "e"]
    msg = str(exc.value)
    assert "{b, b_copy}" in msg and "{a, d, e}" in msg and "c" not in exc.value.terms
    # same analysis without y and with n < p
    with pytest.raises(UnidentifiableTermsError):
        check_identifiable(rng.normal(size=(3, 5)), list("vwxyz"))
    check_identifiable(Z, list("pqrs"))  # full rank: no error


def test_static_gravity_data_cannot_separate_squares_from_bias():
    # |a| = 1 for every static position => 1 = ax^2 + ay^2 + az^2 exactly
    rng = np.random.default_rng(6)
    a = rng.normal(size=(3, 100))
    a /= np.linalg.norm(a, axis=0)
    lib = seed_accelerometer_terms("x")
    with pytest.raises(UnidentifiableTermsError) as exc:
        fit_ols(lib.design({"ax": a[0], "ay": a[1], "az": a[2]}), a[0], lib.names)
    assert sorted(exc.value.terms) == sorted(["1", "ax^2", "ay^2", "az^2"])


def test_nan_and_bad_shapes_are_refused():
    rng = np.random.default_rng(7)
    X, b = _well_conditioned_problem(rng)
    y = X @ b
    y[[3, 9]] = np.nan
    with pytest.raises(ValueError, match="NaN") as exc:
        fit_ols(X, y, ["1", "a", "b", "a*b"])
    assert "2 of 40 rows" in str(exc.value)
    X2 = X.copy()
    X2[0, 1] = np.inf
    with pytest.raises(ValueError, match="X contains inf"):
        fit_ols(X2, X @ b, ["1", "a", "b", "a*b"])
    with pytest.raises(ValueError, match="2 more observation"):
        fit_ols(X[:3], y[:3], ["1", "a", "b", "a*b"])
    with pytest.raises(ValueError, match="names"):
        fit_ols(X, X @ b, ["1", "a", "b"])
    with pytest.raises(ValueError, match="1-D"):
        fit_ols(X, (X @ b)[:, None], ["1", "a", "b", "a*b"])


# ---------------------------------------------------------------------------
# stepwise selection

TRUE_TERMS = ["1", "a", "c", "a*b", "c^2"]
TRUE_COEF = [0.5, 2.0, -1.5, 1.0, 1.2]


def _selection_data(seed: int, n: int = 600, sigma: float = 0.05):
    rng = np.random.default_rng(seed)
    inputs = dict(zip("abc", rng.uniform(-1.0, 1.0, size=(3, n))))
    lib = polynomial(["a", "b", "c"], 2)
    y = lib.subset(TRUE_TERMS).design(inputs) @ np.array(TRUE_COEF) + rng.normal(0.0, sigma, n)
    return lib, inputs, y


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("criterion,alpha", [("bic", 0.05), ("f_test", 1e-3)])
def test_forward_selection_finds_the_generating_terms(seed, criterion, alpha):
    lib, inputs, y = _selection_data(seed)
    sel = forward_selection(lib, inputs, y, criterion=criterion, alpha=alpha)
    assert sel.selected == TRUE_TERMS  # library order
    np.testing.assert_allclose(sel.result.coef_, TRUE_COEF, atol=0.03)
    adds = [h["term"] for h in sel.history if h["action"] == "add"]
    assert sorted(adds) == sorted(TRUE_TERMS[1:])
    assert adds[0] == "a"  # the strongest effect enters first
    json.dumps(sel.to_dict(), allow_nan=False)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("criterion,alpha", [("bic", 0.05), ("f_test", 1e-3)])
def test_backward_elimination_finds_the_generating_terms(seed, criterion, alpha):
    lib, inputs, y = _selection_data(seed)
    sel = backward_elimination(lib, inputs, y, criterion=criterion, alpha=alpha)
    assert sel.selected == TRUE_TERMS
    removed = {h["term"] for h in sel.history if h["action"] == "remove"}
    assert removed == set(lib.names) - set(TRUE_TERMS)


def test_selection_skips_rank_deficient_candidates():
    rng = np.random.default_rng(8)
    a = rng.uniform(-1, 1, 200)
    inputs = {"a": a, "b": a**2}  # b duplicates a^2
    lib = polynomial(["a", "b"], 2)
    y = 1.0 + 2.0 * a + 3.0 * a**2 + rng.normal(0, 0.01, 200)
    fwd = forward_selection(lib, inputs, y)
    skipped = [h for h in fwd.history if h["action"] == "skip"]
    assert skipped and all(h["term"] in ("a^2", "b") for h in skipped)
    assert len({"a^2", "b"} & set(fwd.selected)) == 1
    bwd = backward_elimination(lib, inputs, y)
    assert any(h["action"] == "skip" and h["term"] == "a^2" for h in bwd.history)
    assert set(bwd.selected) == {"1", "a", "b"}
    with pytest.raises(ValueError, match="bic.*aic.*r2_adj.*f_test"):
        forward_selection(lib, inputs, y, criterion="mallows")


# ---------------------------------------------------------------------------
# term libraries


def test_polynomial_and_seed_libraries_have_the_documented_names():
    assert polynomial(["a", "b"], 2).names == ["1", "a", "b", "a^2", "a*b", "b^2"]
    assert polynomial(["a", "b"], 3, cross=False, bias=False).names == ["a", "b", "a^2", "b^2", "a^3", "b^3"]
    assert len(polynomial(["a", "b", "c"], 3)) == 20  # C(3 + 3, 3)
    assert seed_accelerometer_terms("x").names == ["1", "ax", "ax^2", "ay", "ay^2", "az", "az^2", "ay*az"]
    assert seed_accelerometer_terms("y").names[-1] == "ax*az"
    assert seed_accelerometer_terms("z").names[-1] == "ax*az"
    with pytest.raises(ValueError):
        seed_accelerometer_terms("w")


def test_term_library_round_trip_union_subset_and_design():
    lib = polynomial(["ax", "ay", "az"], 3)
    assert TermLibrary.from_names(lib.names).names == lib.names
    assert TermLibrary.from_names(["1", "ax", "ax^2", "ay*az"]).names == ["1", "ax", "ax^2", "ay*az"]
    u = polynomial(["ax", "ay"], 2) + seed_accelerometer_terms("x") + polynomial(["ax", "ay"], 1)
    assert len(u.names) == len(set(u.names))
    assert u.names[:6] == polynomial(["ax", "ay"], 2).names
    assert set(u.names) == set(polynomial(["ax", "ay"], 2).names) | set(seed_accelerometer_terms("x").names)
    assert "az*ay" in u and "ay*az" in u and "ax^3" not in u
    assert lib.subset(["az", "1", "ax*ay"]).names == ["1", "az", "ax*ay"]
    with pytest.raises(KeyError, match="ax\\^7"):
        lib.subset(["ax", "ax^7"])
    t = Term((("ax", 2), ("az", 1)))
    assert (t.name, t.degree) == ("ax^2*az", 3)
    assert Term(()).name == "1" and Term((("ay", 0),)).name == "1"

    rng = np.random.default_rng(9)
    ax, ay, az = rng.normal(size=(3, 7))
    X = seed_accelerometer_terms("x").design({"ax": ax, "ay": ay, "az": az})
    ref = np.column_stack([np.ones(7), ax, ax**2, ay, ay**2, az, az**2, ay * az])
    assert X.shape == (7, 8) and X.dtype == np.float64
    np.testing.assert_allclose(X, ref, rtol=1e-15)
    np.testing.assert_allclose(t.evaluate({"ax": ax, "az": az}), ax**2 * az, rtol=1e-15)
    with pytest.raises(ValueError, match="'az'"):
        seed_accelerometer_terms("x").design({"ax": ax, "ay": ay})


# ---------------------------------------------------------------------------
# property: exact data are recovered to the accuracy the conditioning allows


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    p=st.integers(1, 8),
    extra=st.integers(1, 30),
    spread=st.floats(0.0, 6.0),
    mix=st.floats(0.0, 3.0),
)
def test_exact_fit_recovers_coefficients_within_conditioning(seed, p, extra, spread, mix):
    rng = np.random.default_rng(seed)
    n = p + extra
    mixing = np.eye(p) + mix * rng.normal(size=(p, p))
    X = (rng.normal(size=(n, p)) @ mixing) * 10.0 ** rng.uniform(-spread / 2, spread / 2, p)
    kappa = np.linalg.cond(X)
    assume(np.isfinite(kappa) and kappa < 1e11)
    b = rng.normal(size=p)
    res = fit_ols(X, X @ b, [f"t{j}" for j in range(p)])
    err = np.linalg.norm(res.coef_ - b) / np.linalg.norm(b)
    # backward-stable QR: error <= c * (p + sqrt(n)) * kappa * eps (normal equations: ~kappa^2 * eps)
    assert err <= 8 * (p + math.sqrt(n)) * kappa * EPS


def test_reml_extra_white_variance_kept_only_where_significant():
    """white_variance_reml(level=...): with no extra white noise (cov = K), the likelihood-ratio test
    keeps s^2 > 0 in at most a fraction ``level`` of data sets (binomial bound at 1e-3), where the
    free REML estimate is positive in about half (boundary mixture 50:50); an extra white part five
    times K's diagonal (LR of order n = 80, against the threshold 5.4) is kept every time."""
    from scipy.stats import binom

    from imurig.calibration.gls import white_variance_reml

    rng = np.random.default_rng(12)
    n, reps, level = 80, 100, 0.01
    x = np.linspace(0, np.pi, n)
    X = np.column_stack([np.ones(n), np.cos(x), np.sin(x)])
    K = np.diag(1e-8 * (1 + np.sin(2 * x) ** 2))
    L0 = np.linalg.cholesky(K)
    L1 = np.linalg.cholesky(K + 1e-7 * np.eye(n))
    free, tested, strong = 0, 0, 0
    for _ in range(reps):
        y = X @ [0.1, 1.0, -0.5] + L0 @ rng.standard_normal(n)
        free += white_variance_reml(X, y, K) > 1e-12
        tested += white_variance_reml(X, y, K, level=level) > 0
        strong += white_variance_reml(X, X @ [0.1, 1.0, -0.5] + L1 @ rng.standard_normal(n), K, level=level) > 0
    assert tested <= binom.isf(1e-3, reps, level)
    assert binom.ppf(1e-3, reps, 0.4) <= free <= binom.isf(1e-3, reps, 0.6)
    assert strong == reps
