"""The flight study behind ``imurig flight``: the flight flown twice through the loosely coupled
GPS/INS filter, with the IMU's datasheet-nominal conversions only, then corrected by the
calibrations estimated on the virtual rigs (the report: :mod:`imurig.reports.flight`).

    truth (MuJoCo Citation, or the static tests) -> the IMU drawn from ``seed`` -> raw volts
      + GPS fixes (Euro4 receiver model)
      + calibrations of that IMU: tilt table, turn table, thermal chamber, magnetometer rig
      -> SI samples, nominal or calibrated -> LooseEKF (datasheet or calibrated priors)
      -> errors against the truth, summary

The IMU is the lab drawn from ``seed`` on the stream ``sensor_errors`` (exactly as the
campaigns draw it, :mod:`imurig.kernel.random_streams`), so the tilt-table, turn-table and
thermal campaigns run with the same seed calibrate the very sensors that fly. The flight's own
noise comes from the streams ``flight/sensor-chain`` and ``flight/gps``, distinct from every
campaign's stream.

The pieces live in :mod:`imurig.campaigns.flight_calibration` (rig calibrations and the SI
stream), :mod:`imurig.campaigns.flight_priors` (filter priors, declination) and
:mod:`imurig.campaigns.flight_filter` (alignment, the filter, its errors); this module re-exports
them, so studies and scorers import the flight from here.
"""
from __future__ import annotations

import math
import time
import tracemalloc
from dataclasses import dataclass, replace

import numpy as np

from imurig.campaigns.flight_calibration import (
    calibrations,
    gimbal_field_C,
    imu_stream,
    mag_calibration,
    thermal_calibration,
    thermal_terms,
)
from imurig.campaigns.flight_filter import SETTLE_S
from imurig.campaigns.flight_filter import (
    ALIGN_WINDOW_S,
    align,
    alignment_means,
    errors,
    mag_heading_error_rms_deg,
    run_filter,
    summarise,
)
from imurig.campaigns.flight_priors import (
    FILTER_VARIANTS,
    MAG_SENSITIVITY_SPREAD,
    calibrated_priors,
    datasheet_priors,
    datasheet_values,
    declination_model,
    flight_declination,
    filter_settings,
    gps_error_model,
    imu_noise,
    mag_heading_error_model_datasheet,
    mag_iron_prior_datasheet,
)
from imurig.campaigns.delft_2005 import check_lab
from imurig.campaigns.delft_2005_van import delft_2005_van_plan
from imurig.campaigns.magnetometer import delft_2005_fluxgate
from imurig.flights import ekf
from imurig.flights.gps import GpsReceiver
from imurig.flights.imu import measure_flight
from imurig.flights.plan import simulate_flight
from imurig.flights.truth import static_tests_truth
from imurig.flights.van import VanPlan, simulate_van
from imurig.kernel import random_streams
from imurig.kernel.errors import ConfigError
from imurig.kernel.navdata import GpsFixes
from imurig.kernel.progress import progress
from imurig.sensors.chain import ImuLab

__all__ = [
    "ALIGN_WINDOW_S", "FILTER_VARIANTS", "MAG_SENSITIVITY_SPREAD", "FlightOptions", "FlightStudy", "align",
    "alignment_means", "calibrate", "calibrated_priors", "calibrations", "datasheet_priors", "datasheet_values",
    "declination_model", "errors", "filter_settings", "flight_declination", "flight_lab", "flight_truth", "fly",
    "gimbal_field_C", "gps_error_model",
    "gps_fixes", "imu_noise", "imu_stream", "mag_calibration", "mag_heading_error_model_datasheet",
    "mag_heading_error_rms_deg", "mag_iron_prior_datasheet", "measure_volts", "receiver_fixes", "run_filter",
    "run_filters", "study_summary", "summarise", "thermal_calibration", "thermal_terms",
]


@dataclass
class FlightOptions:
    flight: str = "default"            # "default" (6A's plan), "static" (paper 4.2) or "van" (paper 4.3 ground test)
    seed: int = 2005
    duration_s: float | None = None
    nav_rate_hz: float = 25.0
    imu_rate_hz: float = 100.0
    gps_rate_hz: float = 1.0
    quick_calibration: bool = True
    gps_latency_s: float = 0.0
    gps_time_sigma_s: float = 0.0
    # uncalibrated compass: the fluxgate's installation errors as 12 random-constant states
    # (ekf.FilterConfig.mag_iron_states, compass updating heading, gyro biases and iron only);
    # False: one Gauss-Markov heading-error state instead (consistent but far too cautious, NIS 0.05)
    mag_iron_states: bool = True
    # the filter's states (FILTER_VARIANTS): the paper's 18, or the extended sets of each run
    filter: str = "paper18"
    #: "quiet" (default: every sensor drawn from its datasheet) or "delft-2005": the fluxgate installation of
    #: the Delft 2005 preset (:func:`imurig.campaigns.magnetometer.delft_2005_fluxgate`, hard iron fitted to the
    #: paper's Fig. 5) and, for the van, the ramp angle fitted to the paper's Fig. 9
    #: (:mod:`imurig.campaigns.delft_2005_van`); the inertial sensors stay the drawn ones, which the rig
    #: calibrations of ``seed`` calibrate
    lab: str = "quiet"

    def validate(self):
        if self.flight not in ("default", "static", "van"):
            raise ConfigError(f"unknown flight {self.flight!r}; choose 'default', 'static' or 'van'")
        if self.filter not in FILTER_VARIANTS:
            raise ConfigError(f"unknown filter {self.filter!r}; choose one of {', '.join(FILTER_VARIANTS)}")
        check_lab(self.lab)
        if self.gps_rate_hz > self.imu_rate_hz:
            raise ConfigError(f"GPS rate {self.gps_rate_hz:g} Hz above the IMU rate {self.imu_rate_hz:g} Hz")
        if not (0 < self.nav_rate_hz <= self.imu_rate_hz):
            raise ConfigError("nav rate must be positive and at most the IMU rate")
        if self.duration_s is not None and self.duration_s < SETTLE_S + 5.0:
            raise ConfigError(f"--duration {self.duration_s:g} s leaves no errors to score: the filter's first "
                              f"{SETTLE_S:g} s (its settling after alignment) are left out of the statistics; "
                              f"give at least {SETTLE_S + 5:g} s")
        return self


# ------------------------------------------------------------------ truth, IMU, GPS
def flight_truth(opt: FlightOptions):
    """The flight's truth at the IMU: the default plan flown in MuJoCo, the static tests, or the
    van's ground test driven in MuJoCo (paper section 4.3); cut to ``opt.duration_s`` if given."""
    if opt.flight == "static":
        tr = static_tests_truth(rate_hz=opt.imu_rate_hz)
    elif opt.flight == "van":
        plan = delft_2005_van_plan(opt.imu_rate_hz) if opt.lab == "delft-2005" else VanPlan(rate_hz=opt.imu_rate_hz)
        tr = simulate_van(plan)
    else:
        tr = simulate_flight(progress_bar=True)
    if opt.duration_s is not None:
        tr = tr.slice(tr.time_s[0], tr.time_s[0] + opt.duration_s)
    return tr


def flight_lab(seed: int, lab: str = "quiet") -> ImuLab:
    """The IMU that flies: the lab drawn from ``seed`` as every campaign of that seed draws it; under
    ``lab="delft-2005"`` its fluxgate is the preset's (the magnetometer campaign's of ``seed``, hard iron
    fitted to the paper's Fig. 5), so the van's heading items predict from that fit."""
    drawn = ImuLab.draw(random_streams.generator("sensor_errors", seed))
    if check_lab(lab) == "delft-2005":
        return replace(drawn, magnetometer=delft_2005_fluxgate(seed)[0])
    return drawn


def measure_volts(truth, lab: ImuLab, seed: int) -> dict:
    """Raw volts of the flight (:func:`imurig.flights.imu.measure_flight`: accelerometers, FOGs,
    fluxgate and temperature sensors through the flight's acquisition), on the stream
    ``flight/sensor-chain``."""
    rec = measure_flight(truth, lab, random_streams.seed_sequence("flight/sensor-chain", seed))
    return {k: np.asarray(rec.channels[k]) for k in rec.channels}


def gps_fixes(truth, opt: FlightOptions, seed: int) -> GpsFixes:
    """The Euro4 receiver's fixes of the flight (:func:`receiver_fixes`) on the stream ``flight/gps``."""
    return receiver_fixes(truth, opt, random_streams.generator("flight/gps", seed))


def receiver_fixes(truth, opt, rng: np.random.Generator) -> GpsFixes:
    """Fixes of the Euro4 receiver model (:class:`imurig.flights.gps.GpsReceiver`) at ``opt.gps_rate_hz``,
    drawn from ``rng``, time-tagged as the filter uses them; sets ``opt.gps_latency_s`` and
    ``opt.gps_time_sigma_s``.

    The receiver's tag is the IMU sample at which the logger sees the fix: time of validity
    + latency + jitter, rounded UP to the IMU clock. Time of validity used by the filter:
    tag − latency − Δt_IMU/2 (the mid-point of the rounding interval); what remains lies in
    ±Δt_IMU/2 plus the jitter. The phase of the GPS epochs against the IMU clock is unknown
    and constant (both clocks are stable), so the rounding error is NOT uniform: with the
    epochs on the IMU grid it is ±Δt_IMU/2 with equal odds (the jitter decides). Its largest
    possible variance, (Δt_IMU/2)², is the one used: σ_t² = (Δt_IMU/2)² + σ_jitter²,
    added to R as σ_t² v vᵀ (position) and σ_t² a aᵀ (velocity)."""
    rx = GpsReceiver(rate_hz=opt.gps_rate_hz)
    fx = rx.measure(truth, rng)
    dti = 1.0 / truth.rate_hz if rx.quantise_to_imu else 0.0
    opt.gps_latency_s = float(rx.latency_s + dti / 2)   # time_offset_s is an unknown error: not removed
    opt.gps_time_sigma_s = math.sqrt((dti / 2) ** 2 + rx.time_jitter_s ** 2)
    return GpsFixes(time_s=fx.time_s - opt.gps_latency_s, lat_rad=fx.lat_rad, lon_rad=fx.lon_rad, h_m=fx.h_m,
                    v_N=fx.v_N, sigma_pos_N=fx.sigma_pos_N, sigma_vel_N=fx.sigma_vel_N, mode=fx.mode,
                    valid=np.asarray(fx.valid, bool), meta=fx.meta)


# ------------------------------------------------------------------ the study
@dataclass
class FlightStudy:
    """What :func:`fly` produces: the options it ran with, the truth, the IMU, the GPS fixes, the
    calibrations, each filter run ``{name: (FilterResult, errors, ImuStream)}`` and the summary."""

    opt: FlightOptions
    truth: object
    lab: ImuLab
    gps: GpsFixes
    cals: dict
    runs: dict
    summary: dict


def calibrate(lab: ImuLab, opt: FlightOptions) -> dict:
    """Every rig calibration of the flight's IMU: tilt and turn table (reduced protocols when
    ``opt.quick_calibration``), the magnetometer-rig tumble of its fluxgate, the thermal chamber."""
    cals = calibrations(opt.seed, opt.quick_calibration)
    cals["magnetometer"] = mag_calibration(lab, opt.seed)
    cals["thermal"] = thermal_calibration(opt.seed)
    return cals


def run_filters(truth, volts: dict, gps, lab: ImuLab, cals: dict, opt: FlightOptions) -> tuple[dict, float]:
    """The filter on the nominal and on the calibrated SI stream: ``({"uncalibrated"|"calibrated":
    (FilterResult, errors, ImuStream)}, wall time of the two filter runs in s)``."""
    runs, t_filter = {}, 0.0
    n_epochs = int((truth.time_s[-1] - truth.time_s[0]) * opt.nav_rate_hz)
    with progress(total=2 * n_epochs, desc="flight filter", unit="epoch") as pbar:
        for name, c in (("uncalibrated", None), ("calibrated", cals)):
            stream = imu_stream(truth, volts, lab, c)
            t0 = time.perf_counter()
            res = run_filter(truth, stream, gps, opt, lab, pbar, c)
            t_filter += time.perf_counter() - t0
            runs[name] = (res, errors(res, truth), stream)
    return runs, t_filter


def study_summary(opt: FlightOptions, truth, gps, runs: dict, cals: dict, t_filter: float) -> dict:
    """The numbers of the study (summary.json): errors of both runs, compass errors, the
    magnetometer calibration, filter timing."""
    duration = float(truth.time_s[-1] - truth.time_s[0])
    summary = {"flight": opt.flight, "seed": opt.seed, "duration_s": duration, "vehicle": truth.vehicle,
               "imu_rate_hz": truth.rate_hz, "nav_rate_hz": opt.nav_rate_hz, "gps_mode": getattr(gps, "mode", ""),
               "filter": opt.filter, "lab": opt.lab,
               "n_states": {k: len(r.state_names) for k, (r, _e, _s) in runs.items()},
               "states": {k: list(r.state_names) for k, (r, _e, _s) in runs.items()},
               "runs": {k: summarise(e, r) for k, (r, e, _) in runs.items()},
               "filter_wall_s": t_filter, "real_time_factor": 2 * duration / t_filter}
    decl = declination_model(truth)
    for k, (_r, _e, st) in runs.items():
        summary["runs"][k]["mag_heading_rms_deg"] = mag_heading_error_rms_deg(truth, st, decl)
    mc = cals.get("magnetometer")
    summary["magnetometer_calibration"] = None if mc is None else {
        "method": "two-step ellipsoid fit [Elk01] on a virtual-rig tumble of the flight's magnetometer",
        "tumble_s": mc["tumble_s"], "heading_reference": mc["reference"],
        "rotation_fixed_deg": mc["rotation_fix_deg"],
        "heading_offset_deg": math.degrees(mc["heading_offset_rad"]), **mc["ellipsoid"].to_dict()}
    return summary


def fly(opt: FlightOptions) -> FlightStudy:
    """The whole study (module doc). The summary's ``wall_s`` and ``peak_memory_MB`` are those of
    the study (Python allocations, tracemalloc)."""
    opt.validate()
    tracemalloc.start()
    try:
        t_wall = time.perf_counter()
        truth = flight_truth(opt)
        if abs(truth.rate_hz - opt.imu_rate_hz) > 1e-9:
            opt.imu_rate_hz = truth.rate_hz
        lab = flight_lab(opt.seed, opt.lab)
        volts = measure_volts(truth, lab, opt.seed)
        gps = gps_fixes(truth, opt, opt.seed)
        ekf.check_gps(gps, truth.rate_hz)
        cals = calibrate(lab, opt)
        runs, t_filter = run_filters(truth, volts, gps, lab, cals, opt)
        summary = study_summary(opt, truth, gps, runs, cals, t_filter)
        summary["wall_s"] = time.perf_counter() - t_wall
        summary["peak_memory_MB"] = tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()
    return FlightStudy(opt, truth, lab, gps, cals, runs, summary)
