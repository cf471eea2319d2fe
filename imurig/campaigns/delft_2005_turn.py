"""The Delft 2005 preset on the turn table (issue 17): the seed's documented disturbances of 4.4.x at
sizes fitted to the residual envelopes of Figs. 4.20-4.21 (:mod:`imurig.montecarlo.delft_fit_turn`,
record in assets/delft_2005_turn_fit.json; this module only reads it).

* the gyros' steady-state scale-factor instability, effect ``gyro_scale_instability``
  (datasheet A.2: "SF stability (steady state) 0.03%"), fitted;
* the GPS board's mark-input jitter (seed 4.4.3), fitted; the ADC times edges at its 1 kHz
  samples (1 ms, seed 4.4.3) and the HP 6700 counter at 1 us, as in the quiet lab;
* the slip rings' contact noise (seed 4.4.1, Fig. 4.16) as a density, so that a record at any
  sample rate f_s carries the per-sample rms density sqrt(f_s / 2); the figures cannot tell it from
  the scale factor, so it stays at the quiet lab's level (20 uV per 1 kHz sample);
* the table's once-per-round rate ripple (``TurnTableErrors.ripple``), fitted to Table B.1's scatter about a
  quadratic calibration (:mod:`imurig.montecarlo.delft_fit_simona`, record assets/delft_2005_simona_fit.json):
  the seed documents no ripple, the quiet lab's 1e-3 is a project choice.

``TurnTableCampaign(lab="delft-2005")`` (CLI ``imurig campaign turn-table --lab delft-2005``) builds
its sensor chain through :meth:`Delft2005Turn.apply`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

from imurig.campaigns.delft_2005 import fit_record
from imurig.campaigns.delft_2005_imu import Delft2005Imu
from imurig.rigs.turn_table import TurnTableErrors
from imurig.sensors.chain import ImuLab
from imurig.sensors.effects.gyro_scale_instability import GyroScaleInstability
from imurig.sensors.effects.slip_rings import SlipRingNoise
from imurig.sensors.effects.timer_quantisation import TimerQuantisation
from imurig.sensors.timers import gps_mark_timer, hp6700_counter

FIT_ASSET = "delft_2005_turn_fit.json"
RIPPLE_ASSET = "delft_2005_simona_fit.json"
RIPPLE_SEED_SAYS = ("appendix B, Table B.1: the SIMONA gyros read off a voltmeter at some moment of a round timed by the "
                    "stopwatch; their scatter about a quadratic calibration (0.020-0.027 deg/s) bounds what the table's "
                    "rate does within a round")
GPS_JITTER_SEED_SAYS = ("4.4.3: 'The GPS board internal clock is corrected by the GPS system continuously and reaches a "
                        "higher accuracy as the time measurement with the ADC card'")


def fitted_turn_sizes() -> dict:
    """The turn-table fit's record (Fig. 4.20)."""
    return fit_record(FIT_ASSET, "imurig.montecarlo.delft_fit_turn")


def fitted_ripple() -> dict:
    """The ripple fit's record (Table B.1)."""
    return fit_record(RIPPLE_ASSET, "imurig.montecarlo.delft_fit_simona")


@dataclass(frozen=True)
class Delft2005Turn:
    """The turn table's preset sizes (SI: relative scale factor, s, V/sqrt(Hz))."""

    sf_sigma: float
    gps_jitter_s: float
    slip_density_V_rtHz: float
    sf_tau_s: float = 10.0
    #: the table's relative once-per-round rate ripple (Table B.1's fit; the quiet lab: 1e-3)
    table_ripple: float = TurnTableErrors.ripple

    @classmethod
    def fitted(cls) -> "Delft2005Turn":
        s = fitted_turn_sizes()["sizes"]
        return cls(sf_sigma=s["sf_sigma"]["value"], gps_jitter_s=s["gps_jitter_s"]["value"],
                   slip_density_V_rtHz=s["slip_density_V_rtHz"]["value"],
                   table_ripple=fitted_ripple()["sizes"]["table_ripple"]["value"])

    def table_errors(self, mains_hz: float = 50.0) -> TurnTableErrors:
        """The quiet table's physics on ``mains_hz`` with the preset's ripple."""
        return TurnTableErrors(mains_hz=mains_hz, ripple=self.table_ripple)

    def slip_rings(self, sample_rate_hz: float, enabled: bool = True) -> SlipRingNoise:
        """The slip rings at a record's sample rate: rms per sample = density sqrt(f_s / 2)."""
        return SlipRingNoise(enabled=enabled, rms_V=self.slip_density_V_rtHz * math.sqrt(sample_rate_hz / 2))

    def apply(self, lab: ImuLab, sample_rate_hz: float, slip_rings: bool = True) -> ImuLab:
        """The quiet chain ``lab`` with the preset's slip rings, timers, gyro scale-factor wander and the
        seed's own gyro scale factors (Table B.1, :mod:`imurig.campaigns.delft_2005_imu`)."""
        gps = replace(gps_mark_timer(), jitter_s=self.gps_jitter_s)
        sf = GyroScaleInstability(enabled=True, sigma=self.sf_sigma, tau_s=self.sf_tau_s)
        return replace(lab, slip_rings=self.slip_rings(sample_rate_hz, slip_rings), timers=(gps, hp6700_counter()),
                       effects=(*lab.effects, sf), gyros=Delft2005Imu.estimated().gyros(lab.gyros))

    def describe(self) -> list[dict]:
        """One row per disturbance: size, SE, fitted or not, the seed's sentence."""
        s = fitted_turn_sizes()["sizes"]
        return [{"effect": GyroScaleInstability.name, "size": f"sigma {self.sf_sigma:.3g} (tau {self.sf_tau_s:g} s)",
                 "fitted": True, "se": s["sf_sigma"]["se"], "seed_says": GyroScaleInstability.seed_says},
                {"effect": TimerQuantisation.name + " (GPS mark)", "size": f"jitter {self.gps_jitter_s * 1e3:.3g} ms",
                 "fitted": True, "se": s["gps_jitter_s"]["se"], "seed_says": GPS_JITTER_SEED_SAYS},
                {"effect": "table rate ripple (once per round)", "size": f"{self.table_ripple:.2g} of the rate",
                 "fitted": True, "se": fitted_ripple()["sizes"]["table_ripple"]["se"], "seed_says": RIPPLE_SEED_SAYS},
                {"effect": SlipRingNoise.name, "size": f"{self.slip_density_V_rtHz * 1e6:.3g} uV/sqrt(Hz)",
                 "fitted": False, "se": None, "seed_says": SlipRingNoise.seed_says},
                *[r for r in Delft2005Imu.estimated().describe() if "scale factor" in r["effect"]]]
