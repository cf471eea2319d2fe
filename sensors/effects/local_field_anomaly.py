"""A local anomaly of the geomagnetic field at the site (seed 4.7; paper 4.3): the calibration
assumes the IGRF field, but steel in the building adds a field fixed in the lab.

    B_W = B_IGRF + dB                              [T, ENU]

Stage "rig": the magnetometer rig's site (``AnomalousSite`` of the magnetometer diagnosis'
concealed cases) adds dB through :meth:`LocalFieldAnomaly.inject`.

Diagnosis (:class:`MagView`, either twin): the indicated field gains A R_CW dB; only dB's
components across the IGRF field are tested (u1 horizontal: a declination error; u2 in the
magnetic meridian: an inclination error), columns stacked(A R_CW u) (nT). The component along
the field scales the three axes alike and is absorbed by the gains. Truth map: dB . u_i / (1 +
dB . B^ / |B|) (nT): the gains' absorption of the along-field part rescales the rest.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects._fluxgate import NT, case_truth
from imurig.sensors.effects.base import Candidate, Effect, Param
from imurig.sensors.effects.views import MagView, across_field


@dataclass
class LocalFieldAnomaly(Effect):
    """dB (3,) T in the lab frame W (ENU)."""

    anomaly_W_T: np.ndarray = field(default_factory=lambda: np.zeros(3))

    name: ClassVar[str] = "local_field_anomaly"
    order: ClassVar[int] = 214
    stage: ClassVar[str] = "rig"
    physics: ClassVar[str] = ("the local field differs from the IGRF model at the site (a local anomaly fixed in "
                              "the lab, e.g. steel in the building): its components across the IGRF field (nT; u1 "
                              "horizontal = declination error, u2 = inclination error)")
    seed_section: ClassVar[str] = "4.6-4.7; paper 4.3"
    seed_says: ClassVar[str] = ("the variation of the magnetic field vector of the earth can be described with the "
                                "International Geomagnetic Reference Field model; the calibration assumes it at the "
                                "site")
    params: ClassVar[tuple] = (Param("dB_u1_nT", "nT", note="across the field, horizontal (declination)"),
                               Param("dB_u2_nT", "nT", note="across the field, in the meridian (inclination)"))
    views: ClassVar[tuple] = (MagView.kind,)

    def __post_init__(self):
        self.anomaly_W_T = np.broadcast_to(np.asarray(self.anomaly_W_T, float), (3,)).copy()

    def inject(self, B_W: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """B_W + dB (T, ENU)."""
        return B_W + self.anomaly_W_T

    def candidates(self, view) -> list[Candidate]:
        if not isinstance(view, MagView):
            return []
        u1, u2 = view.across_field_W()
        A, Rb = view.calibration, view.R_CW
        return [Candidate(self.name, self.physics, ("dB_u1_nT", "dB_u2_nT"),
                          lambda _: np.column_stack([view.stacked(np.einsum("ij,njk,k->ni", A, Rb, u))
                                                     for u in (u1, u2)]))]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """From the case's anomaly and the IGRF field it was added to (truth["magnetometer_diagnosis"])."""
        c = case_truth(truth)
        if c.get("anomaly_W_T") is None:
            return {"dB_u1_nT": 0.0, "dB_u2_nT": 0.0}
        dB, B_W = np.asarray(c["anomaly_W_T"], float), np.asarray(c["igrf_field_W_T"], float)
        Bhat = B_W / np.linalg.norm(B_W)
        scale = 1 + dB @ Bhat / np.linalg.norm(B_W)
        return {f"dB_{k}_nT": float(dB @ u * NT / scale) for k, u in zip(("u1", "u2"), across_field(B_W))}
