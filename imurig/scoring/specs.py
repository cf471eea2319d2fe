"""The named campaigns an estimator is scored on: name, kind, fixed seed and how to build it.

This module is light (the command line lists the names from it); the campaigns themselves,
with their MuJoCo rigs, are built by :func:`CampaignSpec.make` when one is simulated
(:class:`imurig.scoring.campaigns.BenchCampaign`). The table of names and what each
estimates: :mod:`imurig.scoring.campaigns`.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from imurig.kernel.errors import ImurigError

ACC_UNITS = {"sensitivity": "V/(m/s^2)", "misalignment": "rad", "bias": "m/s^2", "nonlinearity": "1/(m/s^2)"}
GYRO_UNITS = {"sensitivity": "V/(rad/s)", "misalignment": "rad", "bias": "rad/s", "nonlinearity": "1/(rad/s)"}


def triad_names(axes) -> list[str]:
    """Parameter names in the order of TriadCalibration.physical_parameters."""
    return ([f"sensitivity_{a}" for a in axes]
            + [f"misalignment_{axes[i]}{axes[j]}" for i in range(3) for j in range(3) if i != j]
            + [f"bias_{a}" for a in axes] + [f"nonlinearity_{a}" for a in axes])


@dataclass(frozen=True)
class CampaignSpec:
    """A named campaign: ``make(seed)`` builds the campaign object (with ``simulate()``)."""

    name: str
    kind: str
    description: str
    seed: int
    make: Callable[[int], object]


def _tilt_quick(seed):
    # heavy (the rig's MuJoCo model): loaded when the campaign is built, not for `imurig --help`
    from imurig.campaigns.tilt_table import TiltTableCampaign
    from imurig.rigs.tilt_table import TiltTableProtocol

    return TiltTableCampaign(protocol=TiltTableProtocol(theta_deg=(0, 30, 60, 90), phi_deg=(0, 60, 120, 180, 240, 300),
                                                        dwell_s=2.0, settle_s=1.0, slew_rate_deg_s=60.0), seed=seed)


def _tilt_full(seed):
    # heavy (the rig's MuJoCo model): loaded when the campaign is built, not for `imurig --help`
    from imurig.campaigns.tilt_table import TiltTableCampaign

    return TiltTableCampaign(seed=seed)


def _turn_quick(seed):
    # heavy (the rig's MuJoCo model): loaded when the campaign is built, not for `imurig --help`
    from imurig.campaigns.turn_table import TurnTableCampaign
    from imurig.rigs.turn_table import TurnTableProtocol

    return TurnTableCampaign(protocol=TurnTableProtocol(dial_rates_dps=(40, 70, 100), min_window_s=4.0, settle_s=2.0,
                                                        remount_s=30.0), seed=seed)


def _turn_full(seed):
    # heavy (the rig's MuJoCo model): loaded when the campaign is built, not for `imurig --help`
    from imurig.campaigns.turn_table import TurnTableCampaign

    return TurnTableCampaign(seed=seed)


def _thermal_quick(seed):
    # heavy (the rig's MuJoCo model): loaded when the campaign is built, not for `imurig --help`
    from imurig.campaigns.thermal import ThermalCampaign
    from imurig.rigs.thermal_chamber import ThermalProfile

    return ThermalCampaign(profile=ThermalProfile(low_C=-30.0, high_C=30.0, step_C=20.0, soak_s=600.0,
                                                  attitude_dwell_s=20.0), seed=seed)


def _thermal_full(seed):
    # heavy (the rig's MuJoCo model): loaded when the campaign is built, not for `imurig --help`
    from imurig.campaigns.thermal import ThermalCampaign

    return ThermalCampaign(seed=seed)


def _mag(seed):
    # heavy (the rig's MuJoCo model): loaded when the campaign is built, not for `imurig --help`
    from imurig.campaigns.magnetometer import MagnetometerCampaign

    return MagnetometerCampaign(seed=seed)


CAMPAIGNS: dict[str, CampaignSpec] = {s.name: s for s in [
    CampaignSpec("tilt-table-quick", "tilt-table", "accelerometers on the tilt table, 48 positions x 2 s", 1,
                 _tilt_quick),
    CampaignSpec("tilt-table", "tilt-table", "accelerometers on the tilt table, the seed's 240 positions x 15 s",
                 2005, _tilt_full),
    CampaignSpec("turn-table-quick", "turn-table", "gyros on the turn table, dial 40/70/100 deg/s, 18 steps", 1,
                 _turn_quick),
    CampaignSpec("turn-table", "turn-table", "gyros on the turn table, the seed's final schedule, 54 steps", 2005,
                 _turn_full),
    CampaignSpec("thermal-quick", "thermal", "thermal chamber -30..+30 C, 20 C steps, two cycles", 1,
                 _thermal_quick),
    CampaignSpec("thermal", "thermal", "thermal chamber -50..+50 C, 10 C steps, two cycles (seed 4.5)", 2005,
                 _thermal_full),
    CampaignSpec("magnetometer", "magnetometer", "fluxgate with hard and soft iron: circle, tumble, swing", 2005,
                 _mag),
]}
QUICK = ("tilt-table-quick", "turn-table-quick", "thermal-quick", "magnetometer")


def get_spec(name: str) -> CampaignSpec:
    if name not in CAMPAIGNS:
        raise ImurigError(f"unknown campaign {name!r}; choose from {sorted(CAMPAIGNS)}")
    return CAMPAIGNS[name]
