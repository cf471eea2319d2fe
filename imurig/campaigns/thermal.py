"""The thermal campaign (seed section 4.5): chamber profile, two cycles, six attitudes per step.

    ThermalProfile -> ThermalChamber (air temperature, attitudes, static truth)
      -> ImuLab (thermal lags, temperature polynomials and hysteresis, 10 Hz averaged logging)
      -> Recording -> six-position bias/scale per step -> polynomial fits vs sensor temperature
      -> coefficients vs the noise-free twin (the same analysis on the true sensors' output)
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np

from imurig.calibration.thermal import ThermalCalibration, branch_gap, step_table
from imurig.campaigns.delft_2005 import check_lab
from imurig.campaigns.delft_2005_imu import Delft2005Imu
from imurig.kernel import random_streams
from imurig.kernel.errors import ScheduleError
from imurig.kernel.recording import Recording
from imurig.rigs.thermal_chamber import ThermalChamber, ThermalProfile
from imurig.sensors.accelerometer import CurrentTemperatureSensor, QFlexTriad
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.chain import ImuLab
from imurig.sensors.disturbances import PeopleTransients, PumpVibration
from imurig.sensors.gyro import FOGTriad
from imurig.kernel.site import Site

Z_BOUND = 4.0
THERMAL_SCAN = ("acc_x", "acc_y", "acc_z", "gyro_p", "gyro_q", "gyro_r",
                "temp_acc_x", "temp_acc_y", "temp_acc_z", "temp_box")


def sensor_from_truth(cls, d: dict):
    """Rebuild a sensor dataclass from its truth dict."""
    return cls(**{k: (tuple(map(tuple, v)) if k == "noise_bands" else v) for k, v in d.items()
                  if k in cls.__dataclass_fields__})


@dataclass
class ThermalCampaign:
    profile: ThermalProfile = field(default_factory=ThermalProfile)
    seed: int = 2005
    start_time: str = "2005-06-20T08:00:00+02:00"
    gyro_bias_tempco_dps_per_C: float = 2e-4
    gyro_scale_variation: float = 0.05
    site: Site = field(default_factory=Site)
    #: "quiet" (default) or "delft-2005": the seed's own gyros (Table B.1 scale factors, Fig. 2's r-gyro bias
    #: temperature coefficient; :mod:`imurig.campaigns.delft_2005_imu`)
    lab: str = "quiet"

    def to_dict(self) -> dict:
        return asdict(self)

    def build(self):
        """Chamber and sensor chain with their (seeded) errors, and the chain's stream
        (``campaign/thermal/sensor-chain``, :mod:`imurig.kernel.random_streams`)."""
        base = ImuLab.draw(random_streams.generator("sensor_errors", self.seed))
        rng = random_streams.generator("gyro_thermal", self.seed)
        # the VG941-3AM datasheet: scale factor varies 5 % over -30..+71 C; bias drifts with temperature
        gy = replace(base.gyros,
                     bias_tempco_rad_s_per_K=rng.uniform(-1, 1, 3) * self.gyro_bias_tempco_dps_per_C * np.pi / 180,
                     scale_tempco_per_K=rng.uniform(-1, 1, 3) * self.gyro_scale_variation / 101.0)
        if check_lab(self.lab) == "delft-2005":
            gy = Delft2005Imu.estimated().thermal_gyros(gy)
        lab = replace(base, gyros=gy, adc=DAQ6036E(scan_list=THERMAL_SCAN, sample_rate_hz=self.profile.sample_rate_hz,
                                   averaging=int(round(1000 / self.profile.sample_rate_hz))),
                      pump=PumpVibration(enabled=False), people=PeopleTransients(enabled=False))
        return ThermalChamber(site=self.site), lab, random_streams.seed_sequence("campaign/thermal/sensor-chain",
                                                                                 self.seed)

    def check_identifiable(self) -> None:
        """Refuse, before simulating, a profile with no more steps than the thermal models have terms."""
        pts = self.profile.validate().setpoints()
        need = ThermalCalibration().terms_needed(hysteresis=len({b for _, b, _ in pts}) == 2)
        if len(pts) <= need:
            raise ScheduleError(f"this profile gives {len(pts)} temperature steps, and the thermal models have up to "
                                f"{need} terms: least squares needs more steps than terms; widen --low/--high, "
                                "shrink --step or add --cycles")

    def simulate(self) -> Recording:
        self.check_identifiable()
        chamber, lab, ss = self.build()
        rig = chamber.simulate(self.profile, self.start_time)
        rec = lab.measure(rig, ss)
        rec.meta["campaign"] = {"name": "thermal", **self.to_dict()}
        return rec


def twin_channels(rec: Recording) -> dict:
    """Noise-free sensor outputs from the truth (the noise-free twin's channels, volts)."""
    t = rec.truth["sensors"]
    acc = sensor_from_truth(QFlexTriad, t["accelerometers"])
    gy = sensor_from_truth(FOGTriad, t["gyros"])
    ts = rec.truth_signals
    f = np.stack([ts[f"f_C_{a}"] for a in "xyz"], 1)
    w = np.stack([ts[f"w_C_{a}"] for a in "xyz"], 1)
    va = acc.ideal_voltage(f, ts["T_acc"], ts["h_acc"])
    vg = gy.ideal_voltage(w, ts["T_gyro"])
    out = {f"acc_{a}": va[:, j] for j, a in enumerate("xyz")}
    out.update({f"gyro_{a}": vg[:, j] for j, a in enumerate("pqr")})
    for name, T in (("temp_acc_x", ts["T_acc"]), ("temp_acc_y", ts["T_acc"]), ("temp_acc_z", ts["T_acc"]),
                    ("temp_box", ts["T_box"])):
        sd = dict(t.get("temperature_sensors", {}).get(name, {}))
        sd["noise_V_rms"] = 0.0
        out[name] = CurrentTemperatureSensor(**sd).voltage(T, np.random.default_rng(0))
    return out


def compare(fit: ThermalCalibration, twin: ThermalCalibration | None = None) -> list[dict]:
    rows = []
    unit = {"acc_bias": "m/s^2", "acc_scale": "1", "gyro_bias": "rad/s"}
    for key, r in fit.results_.items():
        tw = None if twin is None else twin.results_.get(key)
        kind = key.rsplit("_", 1)[0]
        for n, est, se in zip(r.names, r.coef_, r.std_error_):
            inj = None if tw is None else float(tw.coef(n))
            k = 0 if n in ("1", "hysteresis") else (1 if n == "dT" else int(n.split("^")[1]))
            u = unit[kind] + ("" if k == 0 else f"/K^{k}" if k > 1 else "/K")
            rows.append({"name": f"{key}:{n}", "unit": u, "injected": inj, "estimate": float(est),
                         "std_error": float(se), "z": None if inj is None else float((est - inj) / se)})
    for r in rows:
        r["within_bound"] = None if r["z"] is None else bool(abs(r["z"]) <= Z_BOUND)
    return rows


def analyse(rec: Recording) -> dict:
    table = step_table(rec)
    fit = ThermalCalibration().fit(table)
    out = {"table": table, "fit": fit}
    if rec.truth and "T_acc" in rec.truth_signals:
        twin_table = step_table(rec, channels=twin_channels(rec))
        twin = ThermalCalibration().fit(twin_table)
        out.update(twin_table=twin_table, twin=twin, coefficients=compare(fit, twin))
    else:
        out["coefficients"] = compare(fit)
    gaps = {}
    for j, a in enumerate("xyz"):
        g = branch_gap(table, "acc_bias", j)
        g_tw = branch_gap(out["twin_table"], "acc_bias", j)["mean_gap"] if "twin_table" in out else None
        gaps[f"acc_bias_{a}"] = {"measured_gap_m_s2": g["mean_gap"], "injected_gap_m_s2": g_tw,
                                 "injected_hysteresis_m_s2": (rec.truth["sensors"]["accelerometers"]
                                                              ["bias_hysteresis_m_s2"][j] if rec.truth else None)}
    out["hysteresis"] = gaps
    # what the correction buys: the spread of the six-position bias over temperature, before and after
    spread = {}
    for j, a in enumerate("xyz"):
        b = table["acc_bias"][:, j]
        s = np.where(table["branch"] == "up", 0.5, -0.5)
        corr = b - fit.predict(f"acc_bias_{a}", table["T_acc"][:, j], s) + fit.results_[f"acc_bias_{a}"].coef_[0]
        spread[f"acc_bias_{a}"] = {"before_m_s2": float(np.std(b, ddof=1)), "after_m_s2": float(np.std(corr, ddof=1))}
    for j, a in enumerate("pqr"):
        b = table["gyro_bias"][:, j]
        s = np.where(table["branch"] == "up", 0.5, -0.5)
        corr = b - fit.predict(f"gyro_bias_{a}", table["T_box"], s) + fit.results_[f"gyro_bias_{a}"].coef_[0]
        spread[f"gyro_bias_{a}"] = {"before_rad_s": float(np.std(b, ddof=1)), "after_rad_s": float(np.std(corr, ddof=1))}
    out["spread"] = spread
    return out
