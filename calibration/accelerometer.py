"""Accelerometer triad calibration on the tilt table (seed sections 4.3.5, Tables 4.4-4.6).

The generic inverse-model machinery is :mod:`imurig.calibration.triad`; this module gives
the accelerometer's channels, inputs (ax, ay, az in m/s^2) and the seed's models.
"""
from __future__ import annotations


from imurig.calibration.paper_models import paper_eq2_terms
from imurig.calibration.terms import TermLibrary, seed_accelerometer_terms
from imurig.calibration.triad import TriadCalibration, TriadSpec, forward_parameters
from imurig.calibration.triad import indicated as _indicated
from imurig.kernel.recording import Recording

AXES = ("x", "y", "z")
ACC = tuple(f"acc_{a}" for a in AXES)
INPUTS = ("ax", "ay", "az")

MODELS = {
    "linear": lambda a: TermLibrary.from_names(["1", "ax", "ay", "az"]),                           # Table 4.4
    "cross": lambda a: TermLibrary.from_names(["1", "ax", "ay", "az", "ax*ay", "ax*az", "ay*az"]),  # Table 4.5
    "seed_final": seed_accelerometer_terms,                                                         # Table 4.6
    "paper_eq2": paper_eq2_terms,                                          # EUCASS paper eq. 2 (to a^4, 12 terms)
    "physical": lambda a: TermLibrary.from_names(["1", "ax", "ay", "az", f"a{a}^2"]),
    "own_axis": lambda a: TermLibrary.from_names(["1", f"a{a}", f"a{a}^2"]),  # a twin without misalignment
}

SPEC = TriadSpec(kind="accelerometer", axes=AXES, channels=ACC, inputs=INPUTS,
                 sensitivity_key="acc_nominal_sensitivity_V_per_m_s2", quantity_unit="m/s^2",
                 cal_prefix="acc_cal_", models=MODELS,
                 sensitivity_hint=", e.g. 1.33 mA/g x 750 ohm = 0.1017")


class AccelerometerCalibration(TriadCalibration):
    """Inverse-model calibration of the accelerometer triad.

    model: 'linear' (Table 4.4), 'cross' (Table 4.5), 'seed_final' (Table 4.6), 'paper_eq2' (the
    EUCASS paper's eq. 2, own axis to the 4th power), 'physical' (linear + own square), 'stepwise', 'backward', or {axis: TermLibrary}.
    """

    SPEC = SPEC


def indicated(rec: Recording, statistic: str = "median", sensitivity=None):
    """Indicated specific force u (m/s^2) per segment or sample; see :func:`triad.indicated`."""
    return _indicated(rec, SPEC, statistic, sensitivity)


def injected_parameters(truth: dict) -> dict:
    """The forward-model parameters the calibration estimates, from a simulation's truth (SI)."""
    acc = truth["sensors"]["accelerometers"]
    return forward_parameters(AXES, acc["sensitivity_V_per_m_s2"], acc["bias_m_s2"], acc["k2_per_m_s2"],
                              acc["misalignment_rad"])
