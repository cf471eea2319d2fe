"""The "Delft 2005" lab preset (issue 17): the virtual lab with the seed's documented imperfections.

The quiet lab (``lab="quiet"``) stays the default of every campaign. ``lab="delft-2005"`` adds,
each as an effect object of :mod:`imurig.sensors.effects` or a table error, with the seed's
sentence that supports it (``seed_says``):

* the table's random angle-setting error, uniform of width ``setting_error_arcmin`` per position
  (rig error ``TiltTableErrors.setting_resolution_rad``; seed 4.3.1: "0.25 arcsec" (report) /
  "0.25 arcmin" (paper)),
* ADC settling crosstalk (``adc_crosstalk``) with the card's time constant ``settling_tau_s`` and the
  y channel's own ``settling_tau_y_s`` (its line's source impedance; seed 4.3.4), and the y line's slow
  settling tail (``adc_slow_settling``: ``slow_tail_alpha``, ``slow_tail_tau_s``; Tab. 4.3's grounded row),
* the day-time sources that the seed switched off for its evening runs (``air_conditioning``,
  ``transformer_hum``), ship passages on the canals (``ship_passages``, evening too), the warm-up
  transient and vibration rectification at their datasheet bounds (no published table constrains
  them; they are listed with ``fitted: false``),
* for the seed's final campaign (Tabs. 4.4-4.6): the phi-plane error its reference leaves out
  (``reference_phi_error``, listing C.1.1 computes the reference from the nominal angles) and that
  day's setting-error width, both fitted to Tabs. 4.4-4.5 (:mod:`imurig.montecarlo.delft_fit_44`;
  ``final_setting_error_rad``, ``reference_phi_error_rad``),
* the persistent y-channel cable fault (``persistent_cable_fault``) for the campaigns before the
  junction box was repaired (Tab. 4.2; ``cable_fault=True``) and the basement pump's rms by day
  (``building_vibration``), both fitted to Tab. 4.2.

Fitted sizes come from ``delft_2005_fit.json`` (package assets), written by
:func:`imurig.montecarlo.delft_fit.main` (weighted least squares of the simulator to Tab. 4.3,
standard errors in that file; the final campaign's entry by :func:`imurig.montecarlo.delft_fit_44.main`);
this module only reads them.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import numpy as np

from imurig.kernel.errors import ConfigError
from imurig.kernel.units import ARCMIN
from imurig.sensors.effects.adc_crosstalk import AdcCrosstalk
from imurig.sensors.effects.adc_slow_settling import AdcSlowSettling
from imurig.sensors.effects.air_conditioning import AirConditioningVibration
from imurig.sensors.effects.building_vibration import PumpVibration
from imurig.sensors.effects.persistent_cable_fault import PersistentCableFault
from imurig.sensors.effects.reference_phi_error import ReferencePhiError
from imurig.sensors.effects.ship_passages import ShipPassages
from imurig.sensors.effects.transformer_hum import TransformerHum
from imurig.sensors.effects.vibration_rectification import VibrationRectification
from imurig.sensors.effects.warm_up import WarmUp

LABS = ("quiet", "delft-2005")
FIT_ASSET = "delft_2005_fit.json"
#: the seed's sentence for the table's setting error (a rig error, not an effect module)
SETTING_ERROR_SEED_SAYS = ("4.3.1: the angles can be set 'with an accuracy of 0.25 arcsec' (report) / "
                           "'0.25 arcmin' (paper)")


@lru_cache(maxsize=None)
def fit_record(asset: str, refit_module: str) -> dict:
    """A preset fit's record (sizes, standard errors, bounds, chi^2) from the package assets; a
    missing record is refused naming the module that writes it."""
    try:
        text = resources.files("imurig.assets").joinpath(asset).read_text()
    except FileNotFoundError:
        raise ConfigError(f"the Delft 2005 preset's fit record {asset} is missing from the package assets; "
                          f"run 'python -m {refit_module}' to write it") from None
    return json.loads(text)


def fitted_sizes() -> dict:
    """The tilt table's fit record (Tab. 4.2-4.3 and the final campaign)."""
    return fit_record(FIT_ASSET, "imurig.montecarlo.delft_fit")


def check_lab(lab: str) -> str:
    if lab not in LABS:
        raise ConfigError(f"unknown lab {lab!r}; choose one of {list(LABS)} (the quiet lab is the default)")
    return lab


@dataclass(frozen=True)
class Delft2005:
    """The preset's sizes: SI units (rad, s, V); defaults from the fit record."""

    setting_error_rad: float
    settling_tau_s: float
    settling_tau_y_s: float
    cable_offset_V: float
    pump_rms_m_s2: float = 0.03
    cable_dwell_s: float = 60.0
    #: the final campaign's setting-error width and the phi-plane error its reference leaves out (Tabs. 4.4-4.5)
    final_setting_error_rad: float = 0.0
    reference_phi_error_rad: float = 0.0
    #: the y line's slow settling tail (share of a step, time constant; Tab. 4.3's grounded row)
    slow_tail_alpha: float = 0.0
    slow_tail_tau_s: float = 0.0

    @classmethod
    def fitted(cls) -> "Delft2005":
        """The sizes of the fit record: setting error and settling from Tab. 4.3 (the final evening campaign's
        conditions), the pump's rms and the y contact's offset from Tab. 4.2."""
        rec = fitted_sizes()
        s, s42 = rec["sizes"], rec["table_4_2"]["sizes"]
        fin = rec["final_campaign"]["sizes"]
        return cls(setting_error_rad=s["setting_error_arcmin"]["value"] * ARCMIN,
                   settling_tau_s=s["settling_tau_s"]["value"], settling_tau_y_s=s["settling_tau_y_s"]["value"],
                   slow_tail_alpha=s["slow_tail_alpha"]["value"], slow_tail_tau_s=s["slow_tail_tau_s"]["value"],
                   cable_offset_V=s42["cable_offset_V"]["value"], pump_rms_m_s2=s42["pump_rms_m_s2"]["value"],
                   final_setting_error_rad=fin["setting_error_arcmin"]["value"] * ARCMIN,
                   reference_phi_error_rad=fin["reference_phi_error_arcmin"]["value"] * ARCMIN)

    def reference_phi_error(self) -> ReferencePhiError:
        """The final campaign's phi-plane error left out of the reference, as its effect object."""
        return ReferencePhiError(delta_phi_rad=self.reference_phi_error_rad)

    def channel_settling(self) -> dict:
        """Per-channel settling for :class:`imurig.sensors.adc.DAQ6036E` (the y line's own tau)."""
        return {"acc_y": self.settling_tau_y_s}

    def channel_slow_settling(self) -> dict | None:
        """The y line's slow settling tail for :class:`imurig.sensors.adc.DAQ6036E` (None without one)."""
        return {"acc_y": (self.slow_tail_alpha, self.slow_tail_tau_s)} if self.slow_tail_alpha > 0 else None

    def effects(self, cable_fault: bool = False, rng: np.random.Generator | None = None) -> tuple:
        """The lab's own effects (stages specific_force and analog) of the preset."""
        out = [AirConditioningVibration(enabled=True), TransformerHum(enabled=True), ShipPassages(enabled=True),
               WarmUp.from_datasheet(), VibrationRectification.from_datasheet()]
        if cable_fault:
            out.append(PersistentCableFault(enabled=True, channel="acc_y", offset_V=self.cable_offset_V,
                                            dwell_open_s=self.cable_dwell_s, dwell_closed_s=self.cable_dwell_s))
        return tuple(out)

    def describe(self) -> list[dict]:
        """One row per imperfection: name, size, fitted or not, the seed's sentence."""
        rec = fitted_sizes()["sizes"]
        rows = [{"effect": "table setting error", "size": f"{self.setting_error_rad / ARCMIN:.3g} arcmin (width)",
                 "fitted": True, "se": rec["setting_error_arcmin"]["se"], "seed_says": SETTING_ERROR_SEED_SAYS},
                {"effect": AdcCrosstalk.name, "size": f"tau {self.settling_tau_s:.3g} s, y {self.settling_tau_y_s:.3g} s",
                 "fitted": True, "se": [rec["settling_tau_s"]["se"], rec["settling_tau_y_s"]["se"]],
                 "seed_says": AdcCrosstalk.seed_says},
                {"effect": AdcSlowSettling.name, "size": f"y line: alpha {self.slow_tail_alpha:.3g}, "
                 f"tau {self.slow_tail_tau_s:.3g} s", "fitted": True,
                 "se": [rec["slow_tail_alpha"]["se"], rec["slow_tail_tau_s"]["se"]],
                 "seed_says": AdcSlowSettling.seed_says}]
        fin = fitted_sizes()["final_campaign"]["sizes"]
        rows += [{"effect": ReferencePhiError.name, "size": f"{self.reference_phi_error_rad / ARCMIN:.3g} arcmin "
                  "(final campaign, both mountings)", "fitted": True, "se": fin["reference_phi_error_arcmin"]["se"],
                  "seed_says": ReferencePhiError.seed_says},
                 {"effect": "table setting error, final campaign",
                  "size": f"{self.final_setting_error_rad / ARCMIN:.3g} arcmin (width)", "fitted": True,
                  "se": fin["setting_error_arcmin"]["se"], "seed_says": SETTING_ERROR_SEED_SAYS}]
        rows.append({"effect": "building_vibration", "size": f"pump rms {self.pump_rms_m_s2:.3g} m/s^2 by day",
                     "fitted": True, "se": fitted_sizes()["table_4_2"]["sizes"]["pump_rms_m_s2"]["se"],
                     "seed_says": PumpVibration.seed_says})
        for e in self.effects(cable_fault=True):
            rows.append({"effect": e.name, "size": "", "fitted": e.name == PersistentCableFault.name,
                         "se": None, "seed_says": e.seed_says})
        return rows
