"""Tilt-table recordings with a concealed effect, and the truth maps of the suite's tilt cases.

Each builder runs a small tilt-table campaign (:class:`imurig.campaigns.tilt_table.TiltTableCampaign`)
with one effect of the sensor chain or of the site switched on, resized or off; the truth maps
give the value of the effect's parameter the diagnosis should report (the effect's own
``fitted`` map, in the inverse model's terms), and ``found_param`` reads the estimate back from
a diagnosis. The cases themselves are in :mod:`imurig.concealed.suite`.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from imurig.kernel import random_streams
from imurig.campaigns.tilt_table import TiltTableCampaign
from imurig.kernel.errors import ConfigError
from imurig.kernel.recording import Recording
from imurig.rigs.tilt_table import TiltTableProtocol
from imurig.sensors.chain import LabClimate
from imurig.sensors.effects import AdcCrosstalk, ChannelSkew, LeverArm, LooseCable, PumpVibration, TemperatureDrift

SMALL_TILT = TiltTableProtocol(theta_deg=(0, 30, 60, 90), phi_deg=(0, 60, 120, 180, 240, 300), dwell_s=4.0,
                               settle_s=1.0, slew_rate_deg_s=30.0)
# the nonlinearity needs a wider spread of g levels per axis than SMALL_TILT gives
WIDE_TILT = TiltTableProtocol(theta_deg=(0, 15, 30, 45, 60, 75, 90), phi_deg=tuple(range(0, 360, 30)), dwell_s=8.0,
                              settle_s=1.0, slew_rate_deg_s=30.0)
# each axis leans towards both others by +-size (rad); the forward model a_S = (I + M) f
MISALIGNMENT_PATTERN = np.array([[0.0, 1.0, -1.0], [-1.0, 0.0, 1.0], [1.0, 1.0, 0.0]])


def small_tilt(seed, **kw):
    """The SMALL_TILT campaign with the campaign's settings ``kw``, everything else as drawn."""
    return TiltTableCampaign(protocol=SMALL_TILT, seed=seed, **kw).simulate()


def crosstalk_recording(seed, c):
    """Crosstalk of relative size c: choose f_mux so that exp(-1/(f tau)) = c."""
    tau = AdcCrosstalk().settling_tau_s
    f = -1.0 / (tau * math.log(c))
    return small_tilt(seed, mux_frequency_hz=f)


def tilt_lab(seed, change_lab, protocol=SMALL_TILT, **camp_kw):
    """A small tilt-table campaign whose sensor chain is edited by ``change_lab(lab) -> lab``
    (an effect switched on, resized or off) before the measurement."""
    camp = TiltTableCampaign(protocol=protocol, seed=seed, **camp_kw)
    table, lab, ss = camp.build()
    rig = table.simulate(camp.protocol, camp.start_time, random_streams.generator("campaign/tilt-table/rig", seed))
    rec = change_lab(lab).measure(rig, ss)
    rec.meta["campaign"] = {"name": "tilt-table", **camp.to_dict()}
    return rec


def pump_recording(seed, rms):
    """The basement pump at ``rms`` (m/s^2) by day (the campaign started at 10:00)."""
    return tilt_lab(seed, lambda lab: replace(lab, pump=PumpVibration(rms_m_s2=rms, broadband_rms_m_s2=rms / 3)),
                    start_time="2005-06-14T10:00:00+02:00")


def cable_recording(seed, rate_hz):
    """A loose cable spiking at ``rate_hz`` (1/s)."""
    return tilt_lab(seed, lambda lab: replace(lab, cable=LooseCable(enabled=True, rate_hz=rate_hz)))


def accelerometers_recording(seed, misalignment=None, k2=None, protocol=SMALL_TILT):
    """Accelerometers with misalignment of size ``misalignment`` (rad, pattern above) and
    nonlinearity k2 = ``k2`` * (1, -1, 1) (1/(m/s^2)); None keeps the drawn value, 0 removes it."""
    def change(lab):
        kw = {}
        if misalignment is not None:
            kw["misalignment_rad"] = misalignment * MISALIGNMENT_PATTERN
        if k2 is not None:
            kw["k2_per_m_s2"] = k2 * np.array([1.0, -1.0, 1.0])
        return replace(lab, accelerometers=replace(lab.accelerometers, **kw))

    return tilt_lab(seed, change, protocol=protocol)


# ------------------------------------------------------------------ the slews' cases (dynamic twin)
#: a protocol whose slews carry both axes (used by the dynamic cases): 3 x 4 positions per mounting
DYNAMIC_PROTOCOL = {"theta_deg": (0, 45, 90), "phi_deg": (0, 90, 180, 270), "dwell_s": 3.0, "settle_s": 1.0,
                    "slew_rate_deg_s": 30.0}
#: the lever-arm pattern (times the size, m, case frame): the triad's centre off the case's
LEVER_PATTERN = np.array([1.0, -0.75, 0.5])
#: the DAQ's channel count is fixed by the scan list; the skew of acc_y (slot 2) is 2 / f_mux
SKEW_SLOT_Y = 2


def _dyn_record(seed: int, change=None, **camp_kw):
    return tilt_lab(seed, change or (lambda lab: lab), protocol=TiltTableProtocol(**DYNAMIC_PROTOCOL), **camp_kw)


def case_recording(effect: str, seed: int, size: float) -> Recording:
    """A recording with ``effect`` at ``size`` (the sizes: :mod:`imurig.concealed.suite`), everything else as drawn.

    - ``time_delay``: the DAQ's multiplexer skew with acc_y delayed by ``size`` s (f_mux = 2 / size,
      crosstalk off so that only the skew changes with f_mux);
    - ``lever_arm``: the triad senses at ``size`` x (1, -0.75, 0.5) m from the case's reference point;
    - ``wrong_local_gravity``: the recording's site metadata (what the twin uses) states
      g_true (1 + ``size``) while the rig ran at the true local gravity;
    - ``temperature_drift``: the lab air drifts 3 K/h and the accelerometer biases have a linear
      tempco of ``size`` x (1, -1, 1) m/s^2/K (no curvature, no scale tempco).
    """
    if effect == "time_delay":
        rec = _dyn_record(seed, lambda lab: replace(lab, adc=replace(lab.adc, crosstalk_enabled=False,
                                                                      mux_frequency_hz=SKEW_SLOT_Y / size)))
    elif effect == "lever_arm":
        rec = _dyn_record(seed, lambda lab: replace(lab, accelerometers=replace(
            lab.accelerometers, position_C_m=size * LEVER_PATTERN)))
    elif effect == "wrong_local_gravity":
        rec = _dyn_record(seed)
        rec.truth["site_gravity_m_s2"] = rec.meta["site"]["gravity_m_s2"]
        rec.meta["site"] = dict(rec.meta["site"], gravity_m_s2=rec.meta["site"]["gravity_m_s2"] * (1 + size))
    elif effect == "temperature_drift":
        def change(lab):
            acc = replace(lab.accelerometers, bias_tempco_m_s2_per_K=size * np.array([1.0, -1.0, 1.0]),
                          bias_tempco2_m_s2_per_K2=np.zeros(3), bias_tempco3_m_s2_per_K3=np.zeros(3),
                          scale_tempco_per_K=np.zeros(3))
            return replace(lab, accelerometers=acc, climate=LabClimate(drift_C_per_h=3.0))

        rec = tilt_lab(seed, change)
    else:
        raise ConfigError(f"no tilt-table case for '{effect}'")
    return rec


def null_case_recording(effect: str, seed: int) -> Recording:
    """The same kind of record with the effect absent (the twin then lacks nothing)."""
    if effect == "temperature_drift":
        return case_recording(effect, seed, 0.0)
    if effect == "time_delay":  # the seed's 20 kHz skew, which the null twin models
        return _dyn_record(seed)
    return _dyn_record(seed)


def truth_param(effect: str, rec: Recording) -> float:
    """The injected parameter the case's finding estimates, from the effect's own truth map."""
    if effect == "time_delay":  # acc_y's multiplexer skew
        return ChannelSkew().fitted(rec.truth, "acc_y")["tau_s"]
    if effect == "lever_arm":
        return LeverArm().fitted(rec.truth)["dr_x_m"]
    if effect == "wrong_local_gravity":
        return rec.meta["site"]["gravity_m_s2"] / rec.truth["site_gravity_m_s2"] - 1.0
    if effect == "temperature_drift":
        # inverse model: f = u / D - b - kb dT, the column being the temp_acc_x volts (10 mV/K)
        return TemperatureDrift().fitted(rec.truth, "acc_x")["drift"]
    raise ConfigError(f"no truth for '{effect}'")


def found_param(effect: str, d: dict):
    """(estimate, std_error) of the case's parameter in a diagnosis, None if not found."""
    if effect == "wrong_local_gravity":  # what the slews say of g, found or not
        g = d.get("dynamic", {}).get("gravity_check")
        return None if g is None else (g["eps"], g["eps_se"])
    if effect == "temperature_drift":
        src = d["axes"]["x"]["findings"]
    else:
        src = d.get("dynamic", {}).get("findings", [])
    want = {"time_delay": ("time_delay", "y"), "lever_arm": ("lever_arm", "acc"),
            "temperature_drift": ("temperature_drift", None)}[effect]
    for f in src:
        if f["effect"] == want[0] and (want[1] is None or f.get("channel") == want[1]):
            return f["parameters"][0]["estimate"], f["parameters"][0]["std_error"]
    return None
