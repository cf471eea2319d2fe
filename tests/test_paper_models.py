"""The EUCASS 2005 paper's calibration models (its eq. 2 for the accelerometers, eq. 3 for the
gyros) as ``--model paper_eq2`` / ``paper_eq3``: their terms, and exact recovery of an inverse
model of that form from noise-free data (closed form, to rounding)."""
from __future__ import annotations

import numpy as np
import pytest

from imurig.calibration.accelerometer import AccelerometerCalibration
from imurig.calibration.gyro import GyroCalibration
from imurig.calibration.paper_models import paper_eq2_terms, paper_eq3_terms
from imurig.calibration.terms import TermLibrary
from imurig.kernel.recording import Recording


def test_the_papers_terms():
    lib = paper_eq2_terms("x")
    assert lib == TermLibrary.from_names(["1", "ax", "ax^2", "ax^3", "ax^4", "ay", "ay^2", "az", "az^2",
                                          "ax*ay", "ax*az", "ay*az"])
    assert "ay^4" in paper_eq2_terms("y") and "az^4" in paper_eq2_terms("z") and len(paper_eq2_terms("z")) == 12
    assert paper_eq3_terms("p") == TermLibrary.from_names(["1", "wp", "wp^2", "wp^3", "wq", "wr", "wp*wq", "wp*wr",
                                                           "wq*wr"])
    assert "wr^3" in paper_eq3_terms("r") and len(paper_eq3_terms("q")) == 9


def _recording(u, prefix, axes, key, s=0.1):
    n = u.shape[0]
    return Recording(time_s=np.arange(n, dtype=float),
                     channels={f"{prefix}_{a}": s * u[:, j] for j, a in enumerate(axes)},
                     units={f"{prefix}_{a}": "V" for a in axes},
                     segments={"start_s": np.arange(n) - 0.25, "stop_s": np.arange(n) + 0.25},
                     meta={key: [s, s, s]})


@pytest.mark.parametrize("kind", ["acc", "gyro"])
def test_an_inverse_model_of_the_papers_form_comes_back_exactly(kind):
    """Indicated outputs u and a reference r = P(u) with P of the paper's form (random coefficients):
    the fit reproduces every reference to rounding, and the coefficients to the conditioning."""
    rng = np.random.default_rng(5)
    if kind == "acc":
        axes, inputs, terms, cls, key = "xyz", ("ax", "ay", "az"), paper_eq2_terms, AccelerometerCalibration, \
            "acc_nominal_sensitivity_V_per_m_s2"
        d = rng.standard_normal((60, 3))
        u = 9.8 * d / np.linalg.norm(d, axis=1, keepdims=True) * (1 + 0.01 * rng.standard_normal((60, 1)))
        model = "paper_eq2"
    else:
        axes, inputs, terms, cls, key = "pqr", ("wp", "wq", "wr"), paper_eq3_terms, GyroCalibration, \
            "gyro_nominal_sensitivity_V_per_rad_s"
        u = rng.uniform(-5.0, 5.0, (60, 3))
        model = "paper_eq3"
    coef = {a: np.r_[0.01, 1.0, 1e-3 * rng.standard_normal(len(terms(a)) - 2)] for a in axes}
    cols = {n: u[:, j] for j, n in enumerate(inputs)}
    ref = np.column_stack([terms(a).design(cols) @ coef[a] for a in axes])
    cal = cls(model=model).fit(_recording(u, kind, axes, key), ref) if kind == "acc" else \
        cls(model=model, gls=False).fit(_recording(u, kind, axes, key), ref)
    np.testing.assert_allclose(cal.predict(u), ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    for a in axes:
        names, c = cal.models()[a]
        assert TermLibrary.from_names(names) == terms(a)
        X = terms(a).design(cols)
        np.testing.assert_allclose(c, coef[a], rtol=0, atol=1e-12 * np.linalg.cond(X))
