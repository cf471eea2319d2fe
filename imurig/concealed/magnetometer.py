"""Magnetometer recordings with a concealed effect, and the truth maps of the suite's magnetometer cases.

:func:`magnetometer_recording` runs the magnetometer campaign
(:class:`imurig.campaigns.magnetometer.MagnetometerCampaign`) with its fluxgate, the local field,
the fluxgate's temperature offset or its output delay changed by the same mechanisms the
diagnosis' candidates fit (the effect library, :mod:`imurig.sensors.effects`): a local anomaly dB
fixed in the lab (B_W = B_IGRF + dB, :class:`AnomalousSite`), the fluxgate's offset tempco
(injected by the chain), V(t) = V_ideal(t - tau). The metadata carry the IGRF field (what a lab
writes down), the truth the change. ``truth_param`` gives the value of the parameter the
diagnosis should report (the effect's own truth map), ``found_param`` reads it back from a
diagnosis.
"""
from __future__ import annotations

import copy
import functools
import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from imurig.kernel import random_streams
from imurig.campaigns.magnetometer import MAG as MAGC
from imurig.campaigns.magnetometer import MagnetometerCampaign
from imurig.diagnose.magnetometer import PAIRS
from imurig.diagnose.magnetometer_twin import AXES, twin_key, twin_rig
from imurig.kernel.errors import ConfigError
from imurig.kernel.recording import Recording
from imurig.kernel.site import Site, parse_time
from imurig.rigs.mag_rig import MagRig
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.chain import ImuLab
from imurig.sensors.disturbances import PeopleTransients, PumpVibration
from imurig.sensors.effects import ChainContext, LocalFieldAnomaly, MagTimeDelay, by_name
from imurig.sensors.magnetometer import FluxgateTriad


# ---------------------------------------------------------------------------------------------
# forward models used to conceal effects -- the same mechanisms the candidates fit


@dataclass(frozen=True)
class AnomalousSite(Site):
    """A site whose local field is IGRF plus a constant anomaly ``anomaly_W_T`` (ENU, tesla),
    e.g. the steel of a building; B_W = B_IGRF + dB."""

    anomaly_W_T: tuple = (0.0, 0.0, 0.0)

    def magnetic_field_W(self, when):
        return LocalFieldAnomaly(self.anomaly_W_T).inject(super().magnetic_field_W(when))


# ---------------------------------------------------------------------------------------------
# recordings with concealed effects


@functools.lru_cache(maxsize=8)
def _rig_run(anomaly_W_T):
    """The campaign's manoeuvres on the gimbal (deterministic without a taxi wobble: cached)."""
    camp = MagnetometerCampaign()
    plan = [camp.circle, camp.tumble, camp.swing, camp.validation]
    if anomaly_W_T is None:  # the IGRF field: the same gimbal run as the twin's
        rig = MagRig(site=camp.site)
        return twin_rig(twin_key(camp.site.to_dict(), parse_time(camp.start_time).isoformat(), rig.record_rate_hz,
                                   [dict(asdict(m), kind=type(m).__name__) for m in plan]))
    site = AnomalousSite(**camp.site.to_dict(), anomaly_W_T=anomaly_W_T)
    return MagRig(site=site).simulate(plan, camp.start_time, np.random.default_rng(0))


def magnetometer_recording(seed: int, magnetometer=None, anomaly_W_T=None, tempco_T_per_K=None,
                           air_warming_K: float = 0.0, air_tau_s: float = 600.0, delay_s: float = 0.0):
    """The magnetometer campaign (:class:`imurig.campaigns.magnetometer.MagnetometerCampaign`) with
    its fluxgate replaced by ``magnetometer`` (None: the campaign's drawn installation), a local
    field anomaly ``anomaly_W_T`` (ENU, T) in the lab, and a fluxgate offset tempco
    ``tempco_T_per_K`` (3,) [T/K] (the fluxgate's own, injected by the chain at the box
    temperature) while the lab air warms by ``air_warming_K`` (1 - exp(-t/tau)), and a delay
    ``delay_s`` of the sensor's output (e.g. its output filter): V(t) = V_ideal(t - tau).
    The metadata carry the IGRF field (what a lab writes down); the truth carries the anomaly
    and the IGRF field it was added to."""
    camp = MagnetometerCampaign(seed=seed)
    mag = FluxgateTriad.from_datasheet(random_streams.generator("magnetometer_install", seed),
                                       hard_iron_max_nT=camp.hard_iron_max_nT,
                                       soft_iron_max=camp.soft_iron_max, noise_nT_rms=camp.noise_nT)
    if magnetometer is not None:
        mag = magnetometer(mag) if callable(magnetometer) else magnetometer
    if tempco_T_per_K is not None:
        mag = replace(mag, tempco_T_per_K=np.asarray(tempco_T_per_K, float))
    lab = replace(ImuLab(), magnetometer=mag, pump=PumpVibration(enabled=False), people=PeopleTransients(enabled=False),
                  adc=DAQ6036E(scan_list=MAGC + ("temp_box",), sample_rate_hz=100.0, averaging=10))
    if any(getattr(m, "wobble_deg", 0.0) for m in (camp.circle, camp.validation)):
        raise ConfigError("magnetometer_recording caches the rig run and needs wobble-free circles")
    rig = copy.deepcopy(_rig_run(None if anomaly_W_T is None else tuple(map(float, anomaly_W_T))))
    if air_warming_K:
        t = rig.time_s
        rig.truth_signals["T_air"] = 273.15 + lab.climate.temperature_C + air_warming_K * (1 - np.exp(-(t - t[0]) / air_tau_s))
        rig.truth_units["T_air"] = "K"
    truth_extra = {}
    B_true = {c: rig.truth_signals[f"B_C_{c}"].copy() for c in AXES}
    if delay_s:
        delay = MagTimeDelay(delay_s)
        for c in AXES:
            x = rig.truth_signals[f"B_C_{c}"]
            for b in rig.blocks():  # the field the sensor puts out at t is the field at t - tau
                x[b] = delay.inject(x[b], ChainContext(time_s=rig.time_s[b], sample_rate_hz=rig.sample_rate_hz))
        truth_extra["delay_s"] = float(delay_s)
    rec = lab.measure(rig, random_streams.seed_sequence("campaign/magnetometer/sensor-chain", seed))
    for c in AXES:
        rec.truth_signals[f"B_C_{c}"] = B_true[c]
    site_igrf = Site.from_dict(camp.site.to_dict())
    B_W = site_igrf.magnetic_field_W(parse_time(camp.start_time))
    truth_extra["igrf_field_W_T"] = B_W.tolist()
    rec.meta["site"] = site_igrf.to_dict()
    rec.meta["igrf_field_W_T"] = B_W.tolist()
    rec.meta["igrf_horizontal_T"] = float(math.hypot(B_W[0], B_W[1]))
    rec.meta["igrf_total_T"] = float(np.linalg.norm(B_W))
    rec.meta["campaign"] = {"name": "magnetometer", **camp.to_dict()}
    rec.meta["mag_nominal_sensitivity_V_per_T"] = [4.0e4] * 3
    rec.truth["magnetometer_diagnosis"] = {"anomaly_W_T": None if anomaly_W_T is None else list(map(float, anomaly_W_T)),
                                           **truth_extra}
    return rec


# ---------------------------------------------------------------------------------------------
# the concealed-effect cases (used by imurig.concealed.suite)

#: off-diagonal patterns (xy, xz, yz) of the injected soft iron and rotation, and the hard iron's direction
PAIR_PATTERN = np.array([1.0, -0.6, 0.4])
HARD_IRON_PATTERN = np.array([1.0, -0.6, 0.4])
ANOMALY_DIRECTION_W = np.array([0.5, -0.4, 0.77]) / np.linalg.norm([0.5, -0.4, 0.77])
TEMPCO_PATTERN = np.array([1.0, -0.6, 0.8])
AIR_WARMING_K = 3.0


def _ideal(mag, hard=None, soft=None, rot=None):
    """The drawn fluxgate (its gains kept) with only the given installation errors."""
    S, M = np.eye(3), np.zeros((3, 3))
    for (j, k), v in zip(PAIRS, PAIR_PATTERN):
        if soft is not None:
            S[j, k] = S[k, j] = soft * v
        if rot is not None:
            M[j, k], M[k, j] = rot * v, -rot * v
    return replace(mag, hard_iron_T=np.zeros(3) if hard is None else hard * 1e-9 * HARD_IRON_PATTERN,
                   soft_iron=S, misalignment_rad=M)


def case_recording(effect: str, seed: int, size: float) -> Recording:
    """A recording with ``effect`` at ``size`` concealed (units: hard_iron nT, soft_iron 1,
    misalignment rad, local_field_anomaly nT, temperature_drift nT/K, time_delay s)."""
    if effect == "hard_iron":
        return magnetometer_recording(seed, lambda m: _ideal(m, hard=size))
    if effect == "soft_iron":
        return magnetometer_recording(seed, lambda m: _ideal(m, soft=size))
    if effect == "misalignment":
        return magnetometer_recording(seed, lambda m: _ideal(m, rot=size))
    if effect == "local_field_anomaly":
        return magnetometer_recording(seed, anomaly_W_T=ANOMALY_DIRECTION_W * size * 1e-9)
    if effect == "temperature_drift":
        return magnetometer_recording(seed, tempco_T_per_K=TEMPCO_PATTERN * size * 1e-9, air_warming_K=AIR_WARMING_K)
    if effect == "time_delay":
        return magnetometer_recording(seed, _ideal, delay_s=size)
    if effect == "installation":
        return magnetometer_recording(seed)
    raise ConfigError(f"no magnetometer case '{effect}'")


def null_recording(seed: int, twin_model: str) -> Recording:
    """Nothing omitted from the twin: an ideal installation (gains only) for the nominal twin,
    the drawn installation (hard and soft iron, misalignment) in the IGRF field for the calibrated one."""
    return magnetometer_recording(seed, _ideal if twin_model == "nominal" else None)


#: the effect of the library behind each magnetometer case ("installation": its hard iron)
CASE_EFFECT = {"hard_iron": "hard_iron", "installation": "hard_iron", "soft_iron": "soft_iron",
               "misalignment": "mag_misalignment", "local_field_anomaly": "local_field_anomaly",
               "temperature_drift": "mag_temperature_drift", "time_delay": "mag_time_delay"}


def truth_param(effect: str, rec: Recording) -> float:
    """The injected value of the first parameter the diagnosis reports for ``effect``: the
    effect's own truth map (:meth:`imurig.sensors.effects.base.Effect.fitted`) on the recording."""
    if effect not in CASE_EFFECT:
        raise ConfigError(f"no magnetometer case '{effect}'")
    return next(iter(by_name(CASE_EFFECT[effect])().fitted(rec.truth, "mag").values()))


def found_param(effect: str, d: dict):
    """(estimate, std_error) of the first parameter of ``effect`` in a diagnosis, or None."""
    name = "hard_iron" if effect == "installation" else effect
    for f in d["magnetometer"]["findings"]:
        if f["effect"] == name:
            return f["parameters"][0]["estimate"], f["parameters"][0]["std_error"]
    return None


def found_effects(d: dict) -> set:
    """(channel, effect) pairs of a magnetometer diagnosis (channel 'mag': the joint analysis)."""
    out = {("mag", f["effect"]) for f in d["magnetometer"]["findings"]}
    if d.get("unexplained_finding"):
        out.add(("mag", "unexplained_residual"))
    return out
