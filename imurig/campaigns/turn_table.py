"""The turn-table campaigns (seed sections 4.4.1-4.4.4, appendix B, chapter 6).

- :class:`TurnTableCampaign`: the final gyro calibration, rates (1, 2, 4, 8, 10, 20, 40, 80,
  100) x 5/6 deg/s on the dial, both directions, p, q and r up, timed by the HP counter.
- :func:`timer_study`: the r gyro at 1..500 deg/s timed three ways (ADC, GPS mark, HP), Fig. 4.20.
- :func:`arm_study`: accelerometers on the radial arm beyond 1 g (the seed's chapter 6 proposal).
- :func:`simona_virtual`: the SIMONA quick calibration (appendix B) on the virtual table.

    schedule -> TurnTable (MuJoCo + mains factor, slip, ripple, wobble, pulse) -> truth
      -> ImuLab (FOG triad, Q-Flex, slip rings, DAQ, timers) -> Recording
      -> whole-round windows from a timer -> GLS inverse-model fit (GyroCalibration) -> parameters vs truth
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np

from imurig.calibration.gyro import (AXIS_OF_MOUNT, INPUTS, MODELS, GyroCalibration, injected_parameters,
                                     reference_rates, round_windows)
from imurig.calibration.preprocess import segment_statistic
from imurig.calibration.regression import check_identifiable, fit_ols
from imurig.calibration.simona import MANUFACTURER_SENSITIVITY_V_PER_RAD_S
from imurig.calibration.terms import TermLibrary
from imurig.calibration.gls import delta_cov
from imurig.campaigns.delft_2005 import check_lab
from imurig.campaigns.delft_2005_turn import Delft2005Turn
from imurig.campaigns.turn_stream import stream_campaign
from imurig.kernel import random_streams
from imurig.kernel.errors import ConfigError, ScheduleError, UnidentifiableTermsError
from imurig.kernel.recording import Recording
from imurig.rigs.turn_table import TurnTable, TurnTableErrors, TurnTableProtocol
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.chain import TURN_TABLE_SCAN, ImuLab
from imurig.sensors.disturbances import SlipRingNoise
from imurig.sensors.gyro import FOGTriad
from imurig.sensors.voltmeter import AutoscaleVoltmeter
from imurig.kernel.site import Site
from imurig.kernel.units import DEG

Z_BOUND = 4.0
TIMERS = ("adc", "gps_mark", "hp6700")
TIMER_STUDY_RATES_DPS = (1, 2, 4, 8, 10, 20, 40, 60, 80, 100, 150, 200, 300, 400, 500)
SIMONA_DIAL_DPS = (0.5, 1, 1.5, 2, 2.5, 3, 3.5, 4, 4.5, 5, 6, 7, 8, 9, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100)


@dataclass
class TurnTableCampaign:
    """Settings of the virtual gyro calibration on the Genisco C181."""

    protocol: TurnTableProtocol = field(default_factory=TurnTableProtocol)
    seed: int = 2005
    start_time: str = "2005-06-15T18:00:00+02:00"
    timer: str = "hp6700"
    model: str = "physical"
    draw_sensor_errors: bool = True
    slip_rings: bool = True
    mains_hz: float = 50.0
    site: Site = field(default_factory=Site)
    #: "quiet" (default) or "delft-2005": the seed's turn-table disturbances at sizes fitted to Figs. 4.20-4.21
    #: (:mod:`imurig.campaigns.delft_2005_turn`)
    lab: str = "quiet"

    def to_dict(self) -> dict:
        return asdict(self)

    def build(self) -> tuple[TurnTable, ImuLab, np.random.SeedSequence]:
        """Rig and sensor chain with their (seeded) errors, and the chain's stream
        (``campaign/turn-table/sensor-chain``, :mod:`imurig.kernel.random_streams`)."""
        preset = Delft2005Turn.fitted() if check_lab(self.lab) == "delft-2005" else None
        errors = preset.table_errors(self.mains_hz) if preset else TurnTableErrors(mains_hz=self.mains_hz)
        table = TurnTable(errors=errors, site=self.site)
        base = (ImuLab.draw(random_streams.generator("sensor_errors", self.seed)) if self.draw_sensor_errors
                else ImuLab())
        lab = replace(base, adc=DAQ6036E(scan_list=TURN_TABLE_SCAN), slip_rings=SlipRingNoise(enabled=self.slip_rings))
        if preset:
            lab = preset.apply(lab, self.protocol.sample_rate_hz, self.slip_rings)
        return table, lab, random_streams.seed_sequence("campaign/turn-table/sensor-chain", self.seed)

    def check_identifiable(self) -> None:
        """Refuse a schedule that cannot identify the model (before simulating)."""
        p = self.protocol.validate()
        if self.timer not in TIMERS:
            raise ScheduleError(f"unknown timer {self.timer!r}; choose from {TIMERS}")
        model = "linear" if self.model in ("stepwise", "backward") else self.model
        w = []
        f = self.mains_hz / 60
        for st in p.steps(f):
            j, s = AXIS_OF_MOUNT[st.mount]
            v = np.zeros(3)
            v[j] = s * st.dial_dps * f * DEG
            w.append(v)
        w = np.array(w)
        inputs = {n: w[:, k] for k, n in enumerate(INPUTS)}
        for a in "pqr":
            lib = MODELS[model](a)
            try:
                check_identifiable(lib.design(inputs), lib.names)
            except UnidentifiableTermsError as e:
                raise UnidentifiableTermsError(
                    f"this schedule (dial rates {list(p.dial_rates_dps)} deg/s, directions {list(p.directions)}, "
                    f"mountings {list(p.mounts)}) cannot identify the '{model}' model of gyro {a}: {e}. "
                    "Add distinct rates, the other direction, or a mounting with that axis on the table.",
                    e.terms) from None

    def simulate(self, check: bool = True, chain: str = "stream") -> Recording:
        """Simulate the schedule (after refusing an unidentifiable one, unless ``check`` is off:
        the studies below fit their own one-axis models). ``chain="stream"`` (default): the streamed sensor
        chain, ``stream_campaign(camp, keep=True).recording`` (:mod:`imurig.campaigns.turn_stream`), the data of
        ``imurig campaign turn-table`` for the same seed (a lab the stream does not model runs the whole-record
        chain there); ``chain="whole"``: the whole-record chain (:meth:`ImuLab.measure`), the same truth and
        noise models, another realisation of the noise (the stream draws it piece by piece)."""
        if chain == "stream":
            return stream_campaign(self, keep=True, check=check).recording
        if chain != "whole":
            raise ConfigError(f"chain must be 'stream' or 'whole', got {chain!r}")
        if check:
            self.check_identifiable()
        else:
            self.protocol.validate()
        table, lab, ss = self.build()
        rig = table.simulate(self.protocol, self.start_time,
                             random_streams.generator("campaign/turn-table/rig", self.seed))
        return self._measured(lab, rig, ss)

    def _measured(self, lab: ImuLab, rig: Recording, ss: np.random.SeedSequence) -> Recording:
        """The whole-record sensor chain over the rig record ``rig``, with the campaign's metadata and seed."""
        rec = lab.measure(rig, ss)
        rec.meta["campaign"] = {"name": "turn-table", **self.to_dict()}
        rec.truth["seed"] = self.seed
        return rec


# ------------------------------------------------------------------- gyro analysis
def gyro_parameters(cal: GyroCalibration, rec: Recording) -> list[dict]:
    """Physical gyro parameters with injected values (effective, including the table wobble) and z."""
    params = cal.physical_parameters()
    inj = injected_parameters(rec.truth, list(rec.segments["mount"])) if rec.truth else {}
    for p in params:
        v = inj.get(p["name"])
        p["injected"] = None if v is None else float(v)
        p["z"] = None if v is None or p["std_error"] <= 0 else (p["estimate"] - v) / p["std_error"]
        p["within_bound"] = None if p["z"] is None else bool(abs(p["z"]) <= Z_BOUND)
    return params


# ------------------------------------------------------------------- timer study
def timer_study(seed: int = 2005, rates_dps=TIMER_STUDY_RATES_DPS, start_time="2005-06-16T18:00:00+02:00",
                min_window_s: float = 3.0, lab: str = "quiet") -> dict:
    """Section 4.4.3: the r gyro (r up) at each rate, about ``min_window_s`` of whole rounds
    each (at least one), calibrated with the rate from each timer. Returns per timer the
    residuals (deg/s) per step and their envelope."""
    camp = TurnTableCampaign(protocol=TurnTableProtocol(dial_rates_dps=tuple(rates_dps), directions=(1,),
                                                        mounts=("r_up",), min_window_s=min_window_s),
                             seed=seed, start_time=start_time, model="linear", lab=lab)
    # a single axis on the table: fit the r gyro alone, Omega = b0 + b1 V_r + b2 V_r^2 (the
    # square takes up the gyro's nonlinearity, so the residuals show the timers)
    # streamed (the acquisition windows' rows: what the timers' round windows read), or the whole-record chain
    # for a lab the stream does not model
    rec = stream_campaign(camp, check=False, streams=("campaign/timer-study/rig", "campaign/timer-study/sensor-chain")).rec
    out = {"rates_dial_dps": list(rates_dps), "timers": {}}
    true = np.array(rec.truth["rig"]["true_mean_rate_dps"])
    for tm in TIMERS:
        rw, rate = round_windows(rec, tm)
        v = segment_statistic(rw, ["gyro_r"], "mean")[:, 0]
        ref = reference_rates(rw, rate)[:, 2]
        res = fit_ols(np.column_stack([np.ones_like(v), v, v**2]), ref, ["1", "V_r", "V_r^2"])
        r_dps = np.degrees(res.residuals_)
        out["timers"][tm] = {"rate_dps": np.degrees(rate).tolist(), "residual_dps": r_dps.tolist(),
                             "envelope_dps": float(np.max(np.abs(r_dps))), "sigma_res_dps": float(np.degrees(
                                 res.sigma_res)), "rate_error_dps": (np.degrees(rate) - true).tolist(),
                             "rounds": rw.segments["rounds"].tolist(),
                             "scale_mV_per_dps": float(1e3 / np.degrees(res.coef_[1]))}
    out["recording"] = rec
    return out


def round_time_error_at(rate_dps: float = 500.0, resolution_s: float = 1e-3) -> dict:
    """Seed 4.4.2: the angle error per round of a round time with ``resolution_s`` at ``rate_dps``
    is rate x resolution (0.5 deg at 500 deg/s with 1 ms; 0.0005 deg with 1 us)."""
    return {"rate_dps": rate_dps, "resolution_s": resolution_s, "angle_error_deg": rate_dps * resolution_s,
            "rate_error_dps_one_round": rate_dps**2 * resolution_s / 360.0}


# ------------------------------------------------------------------- arm study
def arm_schedule(g_levels=(0.5, 1, 1.5, 2, 2.5, 3, 3.5, 4), radius_m: float = 0.5, g: float = 9.81242231,
                 errors: TurnTableErrors | None = None) -> tuple[float, ...]:
    """Dial rates (deg/s) that give the requested centripetal accelerations (in g) at radius_m."""
    e = errors or TurnTableErrors()
    true = np.degrees(np.sqrt(np.asarray(g_levels, float) * g / radius_m))
    dial = true / (e.mains_factor * (1 - e.slip(true / e.mains_factor)))
    if np.any(dial > 1200):
        raise ScheduleError(f"{max(g_levels)} g at {radius_m} m needs {dial.max():.0f} deg/s on the dial, "
                            "above the C181's 1200 deg/s; lower the g level or lengthen the arm")
    return tuple(float(d) for d in dial)


def arm_study(seed: int = 2005, g_levels=(0.5, 1, 1.5, 2, 2.5, 3, 3.5, 4), radius_m: float = 0.5,
              start_time="2005-06-17T18:00:00+02:00") -> dict:
    """Accelerometer x radial on the arm (r up): f_x = -Omega^2 R (specific force, m/s^2).

    Fits f_ref = b0 + b1 u + b2 u^2 (u = V / s_nom) by least squares on whole-round means,
    with the arm radius' uncertainty propagated; recovers bias (incl. M_xz g, the x axis'
    share of gravity), sensitivity and the second-order nonlinearity k2 = -b2 / b1^2.
    """
    dial = arm_schedule(g_levels, radius_m)
    camp = TurnTableCampaign(protocol=TurnTableProtocol(dial_rates_dps=dial, directions=(1, -1), mounts=("r_up",),
                                                        radius_m=radius_m, min_window_s=10.0),
                             seed=seed, start_time=start_time, model="linear")
    table, lab, _ = camp.build()
    rig = table.simulate(camp.protocol, start_time, random_streams.generator("campaign/arm-study/rig", seed))
    rec = lab.measure(rig, random_streams.seed_sequence("campaign/arm-study/sensor-chain", seed))
    rw, rate = round_windows(rec, "hp6700")
    R = rec.meta["arm_radius_m"]
    sR = rec.meta["arm_radius_sigma_m"]
    s_nom = rec.meta["acc_nominal_sensitivity_V_per_m_s2"][0]
    u = segment_statistic(rw, ["acc_x"], "mean")[:, 0] / s_nom
    f_ref = -rate**2 * R
    lib = TermLibrary.from_names(["1", "ax", "ax^2"])
    res = fit_ols(lib.design({"ax": u}), f_ref, lib.names)
    X = lib.design({"ax": u})
    P = np.linalg.pinv(X)
    cov = res.cov_ + np.outer(P @ (-rate**2), P @ (-rate**2)) * sR**2

    def h(b):
        b0, b1, b2 = b
        return np.array([-b0, s_nom / b1, -b2 / b1**2])

    est = h(res.coef_)
    se = np.sqrt(np.diag(delta_cov(h, res.coef_, cov)))
    params = [{"name": "bias_x_effective", "unit": "m/s^2"}, {"name": "sensitivity_x", "unit": "V/(m/s^2)"},
              {"name": "nonlinearity_x", "unit": "1/(m/s^2)"}]
    if rec.truth:
        # what the intercept estimates: the bias plus everything constant in the x input besides
        # the centripetal reference -- the x axis' share of gravity through misalignment, wobble
        # and levelling: b_x + mean_i([(I + M) f_true]_x + Omega_i^2 R)
        acc = rec.truth["sensors"]["accelerometers"]
        f_true = segment_statistic(rw, ["f_C_x", "f_C_y", "f_C_z"], "mean", source="truth_signals")
        a_x = (f_true @ (np.eye(3) + np.asarray(acc["misalignment_rad"])).T)[:, 0]
        true_rate = segment_statistic(rw, ["w_C_z"], "mean", source="truth_signals")[:, 0]
        R_true = rec.truth["rig"]["arm_radius_m"]
        inj = [acc["bias_m_s2"][0] + float(np.mean(a_x + true_rate**2 * R_true)),
               acc["sensitivity_V_per_m_s2"][0], acc["k2_per_m_s2"][0]]
    else:
        inj = [None] * 3
    for p, e, s, v in zip(params, est, se, inj):
        p.update(estimate=float(e), std_error=float(s), injected=None if v is None else float(v),
                 z=None if v is None else float((e - v) / s))
        p["within_bound"] = None if v is None else bool(abs(p["z"]) <= Z_BOUND)
    lin = fit_ols(X[:, :2], f_ref, ["1", "ax"])
    return {"g_levels": list(g_levels), "radius_m": radius_m, "dial_dps": list(dial), "parameters": params,
            "f_ref_m_s2": f_ref.tolist(), "residual_quadratic_m_s2": res.residuals_.tolist(),
            "residual_linear_m_s2": lin.residuals_.tolist(), "sigma_res_quadratic": res.sigma_res,
            "sigma_res_linear": lin.sigma_res, "max_g": float(np.max(np.abs(f_ref)) / 9.81242231),
            "recording": rec}


# ------------------------------------------------------------------- SIMONA twin
@dataclass
class SimonaSetup:
    """The SIMONA experiment of appendix B on the virtual table.

    Three single-axis gyros, all with their axes along the spin axis (they read alike in
    Table B.1), scale factor about 5.44 mV/(deg/s) (what the real table gives), read by an
    autoscaling voltmeter; a stopwatch started and stopped by the index pulse times one round.
    """

    dial_dps: tuple = SIMONA_DIAL_DPS
    scale_mV_per_dps: float = 5.44
    scale_spread: float = 0.003
    voltmeter: AutoscaleVoltmeter = field(default_factory=AutoscaleVoltmeter)
    sample_rate_hz: float = 100.0
    stopwatch_resolution_s: float = 1e-6
    printed_round_decimals: int | None = 2   # Table B.1 prints round times to 0.01 s
    table: TurnTableErrors = field(default_factory=TurnTableErrors)
    #: the gyros' scale-factor nonlinearity k2 (1/(rad/s), FOGTriad's w + k2 w^2) or None: the drawn one (the
    #: Delft 2005 preset's, fitted to Table B.1: :func:`imurig.campaigns.delft_2005_imu.table_b1_gyro_k2`)
    k2_per_rad_s: tuple | None = None


def simona_virtual(seed: int = 2005, setup: SimonaSetup | None = None) -> Recording:
    """Run the SIMONA experiment on the virtual C181 and return a row-level Recording in the
    format of :func:`imurig.calibration.simona.read_simona` (first row: table at rest)."""
    s = setup or SimonaSetup()
    rng = random_streams.generator("campaign/simona/lab", seed)
    table = TurnTable(errors=s.table)
    proto = TurnTableProtocol(dial_rates_dps=tuple(s.dial_dps), directions=(-1,), mounts=("r_down",),
                              min_window_s=1.0, sample_rate_hz=s.sample_rate_hz)
    rig = table.simulate(proto, "2005-05-20T10:00:00+02:00", rng)
    gy = FOGTriad.from_datasheet(rng, scale_mV_per_dps=s.scale_mV_per_dps, scale_spread=s.scale_spread)
    if s.k2_per_rad_s is not None:
        gy = replace(gy, k2_per_rad_s=np.asarray(s.k2_per_rad_s, float))
    w = np.repeat(rig.truth_signals["w_C_z"][:, None], 3, axis=1)  # all three axes on the spin axis
    v = gy.output_voltage(w, s.sample_rate_hz, rng)
    n_int = max(1, int(round(s.voltmeter.integration_s * s.sample_rate_hz)))
    rows_v, rows_T = [np.zeros(3)], [0.0]
    # at rest: a reading before the table starts
    rest = gy.output_voltage(np.zeros((n_int, 3)), s.sample_rate_hz, rng).mean(axis=0)
    rows_v[0] = s.voltmeter.read(rest, rng)[0]
    pulses = rig.events["pulse_true"]
    for a, b in zip(rig.segments["start_s"], rig.segments["stop_s"]):
        p = pulses[(pulses >= a) & (pulses < b)]
        T_round = float(np.round((p[1] - p[0]) / s.stopwatch_resolution_s) * s.stopwatch_resolution_s)
        rows_T.append(round(T_round, s.printed_round_decimals) if s.printed_round_decimals is not None else T_round)
        # the voltmeter is read at some moment during the timed round
        i0 = int(np.searchsorted(rig.time_s, p[0] + rng.uniform(0, p[1] - p[0] - s.voltmeter.integration_s)))
        rows_v.append(s.voltmeter.read(v[i0:i0 + n_int].mean(axis=0), rng)[0])
    dial = np.concatenate(([0.0], np.asarray(s.dial_dps, float))) * DEG
    nominal = dial * 5 / 6
    expected = np.where(nominal > 0, 2 * np.pi / np.where(nominal > 0, nominal, 1), 0.0)
    V = np.array(rows_v)
    T = np.array(rows_T)
    n = dial.size
    t = np.arange(n, dtype=float)
    ch = {"rate_dial": dial, "rate_nominal": nominal, "expected_round": expected, "measured_round": T,
          "gyro_p": V[:, 0], "gyro_q": V[:, 1], "gyro_r": V[:, 2], "round_measured": (T > 0).astype(float)}
    units = {"rate_dial": "rad/s", "rate_nominal": "rad/s", "expected_round": "s", "measured_round": "s",
             "gyro_p": "V", "gyro_q": "V", "gyro_r": "V", "round_measured": "1"}
    truth = {"gyros": gy.truth(), "voltmeter": s.voltmeter.settings(), "turn_table": table.errors.to_dict(),
             "true_mean_rate_dps": rig.truth["rig"]["true_mean_rate_dps"]}
    return Recording(time_s=t, channels=ch, units=units,
                     segments={"start_s": t.copy(), "stop_s": t + 1, "rate_dial": dial.copy(), "row": np.arange(n)},
                     segment_units={"start_s": "s", "stop_s": "s", "rate_dial": "rad/s", "row": "1"},
                     meta={"rig": "turn_table", "table": "virtual Genisco C181", "direction": "clockwise",
                           "row_recording": True, "source": "imurig virtual SIMONA experiment",
                           "gyro_nominal_sensitivity_V_per_rad_s": {g: MANUFACTURER_SENSITIVITY_V_PER_RAD_S
                                                                    for g in "pqr"}},
                     truth=truth).validate()
