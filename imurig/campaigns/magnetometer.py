"""The magnetometer campaign (seed 4.6-4.7, paper 3.2 and 4.3).

    manoeuvres (level circle, tumble, compass swing, a validation circle) on the MuJoCo gimbal
      -> true field B_C from IGRF (pyIGRF 0.3.3) at the site and date
      -> fluxgate with the installation's hard and soft iron -> DAQ (averaged 100 Hz) -> Recording
      -> two-step calibration: 2-D ellipse (level circle), 3-D ellipsoid (tumble)
      -> heading-domain swing on the compass rose, for comparison
      -> heading error before/after on the validation circle; field norm constancy (paper Fig. 5)

Indicated field m = V / s_nom (tesla): the "manufacturer's calibration" (nominal sensitivity,
no bias). The truth the fits estimate, from the injected sensor (A = G S_soft (I + M),
b = G b_hard, G = s / s_nom):
- 3-D: b and A A' (A is only identifiable up to a rotation);
- 2-D level swing: b2 = b_xy + A_xy,z B_z (the vertical field leaks through the x-y rows of A
  into a constant offset) and A2 A2' with A2 = A[:2, :2].
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np

from imurig.calibration.heading import heading_from_field, wrap_pi
from imurig.calibration.magnetometer import MagnetometerCalibration
from imurig.campaigns.delft_2005 import check_lab
from imurig.campaigns.delft_2005_imu import fig5_hard_iron
from imurig.kernel import random_streams
from imurig.kernel.recording import Recording
from imurig.rigs.mag_rig import CompassSwing, LevelCircle, MagRig, Tumble
from imurig.sensors.adc import DAQ6036E
from imurig.sensors.chain import ImuLab
from imurig.sensors.disturbances import PeopleTransients, PumpVibration
from imurig.sensors.magnetometer import FluxgateTriad
from imurig.kernel.site import Site

Z_BOUND = 4.0
MAG = ("mag_x", "mag_y", "mag_z")
PUBLISHED_H_NT, PUBLISHED_F_NT = 19018.0, 48723.0


@dataclass
class MagnetometerCampaign:
    seed: int = 2005
    start_time: str = "2005-06-21T10:00:00+02:00"
    hard_iron_max_nT: float = 6000.0     # the vehicle's and rack's magnetisation (~10 deg heading error)
    soft_iron_max: float = 0.05
    noise_nT: float = 5.0
    # level to the rig's precision; a tilt during a 2-D swing leaks the vertical field into x-y
    # (0.1 deg ~ 80 nT here) and biases the 2-D fit -- the 3-D fit does not care
    circle: LevelCircle = field(default_factory=lambda: LevelCircle(turns=2, rate_dps=10, wobble_deg=0.0))
    tumble: Tumble = field(default_factory=Tumble)
    swing: CompassSwing = field(default_factory=CompassSwing)
    validation: LevelCircle = field(default_factory=lambda: LevelCircle(turns=1, rate_dps=6, start_heading_deg=17,
                                                                        wobble_deg=0.0, name="validation_circle"))
    site: Site = field(default_factory=Site)
    #: "quiet" (default) or "delft-2005": the hard iron fitted to the paper's Fig. 5
    #: (:mod:`imurig.campaigns.delft_2005_imu`)
    lab: str = "quiet"

    def to_dict(self) -> dict:
        return asdict(self)

    def simulate(self) -> Recording:
        install_rng = random_streams.generator("magnetometer_install", self.seed)
        mag = FluxgateTriad.from_datasheet(install_rng, hard_iron_max_nT=self.hard_iron_max_nT,
                                           soft_iron_max=self.soft_iron_max, noise_nT_rms=self.noise_nT)
        rig = MagRig(site=self.site).simulate([self.circle, self.tumble, self.swing, self.validation], self.start_time,
                                              random_streams.generator("campaign/magnetometer/rig", self.seed))
        if check_lab(self.lab) == "delft-2005":
            # the seed's installation: hard iron fitted to the paper's Fig. 5 on the validation circle's field
            on_circle = manoeuvre_mask(rig, self.validation.name)
            B = np.column_stack([rig.truth_signals[f"B_C_{a}"] for a in "xyz"])[on_circle]
            fit5 = fig5_hard_iron(mag, B)
            mag = replace(mag, hard_iron_T=fit5["hard_iron_T"])
        lab = replace(ImuLab(), magnetometer=mag, pump=PumpVibration(enabled=False), people=PeopleTransients(enabled=False),
                      adc=DAQ6036E(scan_list=MAG + ("temp_box",), sample_rate_hz=100.0, averaging=10))
        rec = lab.measure(rig, random_streams.seed_sequence("campaign/magnetometer/sensor-chain", self.seed))
        rec.meta["campaign"] = {"name": "magnetometer", **self.to_dict()}
        rec.meta["mag_nominal_sensitivity_V_per_T"] = (np.full(3, 4.0e4)).tolist()
        if self.lab == "delft-2005":
            rec.meta["delft_2005_hard_iron_fit"] = {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                                                    for k, v in fit5.items()}
        return rec


def delft_2005_fluxgate(seed: int = 2005) -> tuple[FluxgateTriad, dict]:
    """The Delft 2005 preset's fluxgate installation, as ``MagnetometerCampaign(seed=seed, lab="delft-2005")``
    has it: drawn from the datasheet on the stream ``magnetometer_install``, then the hard iron fitted to the
    paper's Fig. 5 (:func:`imurig.campaigns.delft_2005_imu.fig5_hard_iron`) on the validation circle's true
    field. The rig runs that circle alone (each manoeuvre starts afresh and the circle has no wobble, so its
    field is the full campaign's). Returns (fluxgate, the fit: hard_iron_T, se_T, norm mean and extent).
    Other vehicles carry it (the van of paper Fig. 8: ``imurig flight --flight van --lab delft-2005``)."""
    c = MagnetometerCampaign(seed=seed, lab="delft-2005")
    mag = FluxgateTriad.from_datasheet(random_streams.generator("magnetometer_install", seed),
                                       hard_iron_max_nT=c.hard_iron_max_nT, soft_iron_max=c.soft_iron_max,
                                       noise_nT_rms=c.noise_nT)
    rig = MagRig(site=c.site).simulate([c.validation], c.start_time,
                                       random_streams.generator("campaign/magnetometer/rig", seed))
    fit5 = fig5_hard_iron(mag, np.column_stack([rig.truth_signals[f"B_C_{a}"] for a in "xyz"]))
    return replace(mag, hard_iron_T=fit5["hard_iron_T"]), fit5


def indicated_field(rec: Recording) -> np.ndarray:
    """m = V / s_nom (n, 3) tesla: the manufacturer's calibration."""
    rec.require({c: "V" for c in MAG})
    return rec.stack(MAG) / np.asarray(rec.meta.get("mag_nominal_sensitivity_V_per_T", [4.0e4] * 3))


def manoeuvre_mask(rec: Recording, name: str) -> np.ndarray:
    """Samples of one manoeuvre (its block of the record)."""
    names = [m["name"] for m in rec.meta["manoeuvres"]]
    b = rec.blocks()[names.index(name)]
    mask = np.zeros(rec.n, bool)
    mask[b] = True
    return mask


def true_invariants(rec: Recording) -> dict:
    t = rec.truth["sensors"]["magnetometer"]
    G = np.asarray(t["sensitivity_V_per_T"]) / np.asarray(rec.meta["mag_nominal_sensitivity_V_per_T"])
    A = np.diag(G) @ np.asarray(t["soft_iron"]) @ (np.eye(3) + np.asarray(t["misalignment_rad"]))
    b = G * np.asarray(t["hard_iron_T"])
    return {"A": A, "b": b}


def _aat_names():
    return ["AAt_xx", "AAt_xy", "AAt_xz", "AAt_yy", "AAt_yz", "AAt_zz"]


def analyse(rec: Recording) -> dict:
    m = indicated_field(rec)
    H = rec.meta["igrf_horizontal_T"]
    F = rec.meta["igrf_total_T"]
    out = {"igrf": {"horizontal_nT": H * 1e9, "total_nT": F * 1e9, "published_horizontal_nT": PUBLISHED_H_NT,
                    "published_total_nT": PUBLISHED_F_NT}}
    circ = manoeuvre_mask(rec, "level_circle")
    tum = manoeuvre_mask(rec, "tumble")
    val = manoeuvre_mask(rec, "validation_circle")
    e2 = MagnetometerCalibration("ellipse").fit(m[circ, :2], H)
    e3 = MagnetometerCalibration("ellipsoid").fit(m[tum], F)
    out["ellipse"], out["ellipsoid"] = e2, e3
    out["parameters"] = _invariant_rows(rec, e2, e3, circ)
    # calibrated norm on the tumble
    cal3 = e3.apply(m[tum])
    out["norm_std_nT"] = float(np.std(np.linalg.norm(cal3, axis=1)) * 1e9)
    out["norm_std_manufacturer_nT"] = float(np.std(np.linalg.norm(m[tum], axis=1)) * 1e9)
    out["noise_nT"] = float(rec.truth["sensors"]["magnetometer"]["noise_T_rms"] * 1e9) if rec.truth else None
    sw = _headings(rec, m, e2, val, out)
    out["fig5"] = {"manufacturer": m[val], "calibrated": e3.apply(m[val])}
    out["swing_mask"] = sw
    return out


def _invariant_rows(rec: Recording, e2, e3, circ) -> list[dict]:
    """Parameter rows of the 3-D fit (b, A A') and the 2-D fit (b2, A2 A2') with the injected
    invariants when the recording has its truth."""
    params = []
    truth = true_invariants(rec) if rec.truth else None
    # 3-D: b and the unique entries of A A'
    inj3 = None
    if truth:
        AAt = truth["A"] @ truth["A"].T
        inj3 = [AAt[0, 0], AAt[0, 1], AAt[0, 2], AAt[1, 1], AAt[1, 2], AAt[2, 2], *truth["b"]]
    names3 = _aat_names() + ["b_x", "b_y", "b_z"]
    est3 = [*e3.AAt_[np.triu_indices(3)], *e3.b_]
    se3 = np.sqrt(np.diag(e3.invariant_cov_))
    order = list(e3.invariant_names_)
    for k, n in enumerate(names3):
        params.append(_row(f"3d:{n}", "T" if n.startswith("b") else "1", est3[k], _se_for(order, n, se3, k),
                           None if inj3 is None else inj3[k]))
    # 2-D: b2 (with the vertical leak) and A2 A2'
    A2 = e2.A_
    A2A2 = A2 @ A2.T
    J_rows = _a2a2t_jacobian(e2)
    cov2 = e2.cov_
    est2 = [A2A2[0, 0], A2A2[0, 1], A2A2[1, 1], e2.b_[0], e2.b_[1]]
    se2 = list(np.sqrt(np.diag(J_rows @ cov2[:3, :3] @ J_rows.T))) + list(np.sqrt(np.diag(cov2)[3:5]))
    inj2 = None
    if truth:
        Bz = float(np.mean(rec.truth_signals["B_C_z"][circ]))
        A = truth["A"]
        b2 = truth["b"][:2] + A[:2, 2] * Bz
        T2 = A[:2, :2] @ A[:2, :2].T
        inj2 = [T2[0, 0], T2[0, 1], T2[1, 1], b2[0], b2[1]]
    for k, n in enumerate(["A2A2t_xx", "A2A2t_xy", "A2A2t_yy", "b2_x", "b2_y"]):
        params.append(_row(f"2d:{n}", "T" if n.startswith("b") else "1", est2[k], se2[k],
                           None if inj2 is None else inj2[k]))
    return params


def _headings(rec: Recording, m, e2, val, out: dict):
    """Headings on the validation circle (manufacturer, two-step 2-D, compass swing, 2-D with one
    reference heading) and the swing into ``out``; returns the compass-swing mask."""
    # heading: validation circle, true heading from the rig, declination from IGRF
    B_W = np.asarray(rec.meta["igrf_field_W_T"])
    decl = float(np.arctan2(B_W[0], B_W[1]))
    psi_true = rec.truth_signals["heading"][val] if "heading" in rec.truth_signals else None
    heads = {"manufacturer": heading_from_field(m[val, :2], declination_rad=decl, frame="FLU"),
             "two-step 2-D": heading_from_field(e2.apply(m[val, :2]),
                                                declination_rad=decl, frame="FLU")}
    # the swing: 12 headings on the rose, indicated with the manufacturer's calibration
    sw = manoeuvre_mask(rec, "compass_swing")
    seg = rec.segments
    ind, rose = [], []
    for i, s in enumerate(rec.segment_slices()):
        if seg["manoeuvre"][i] != "compass_swing":
            continue
        ind.append(float(np.angle(np.mean(np.exp(1j * heading_from_field(m[s, :2], declination_rad=decl,
                                                                          frame="FLU"))))))
        rose.append(float(seg["heading_set"][i]))
    swing = MagnetometerCalibration("swing").fit(np.mod(ind, 2 * np.pi), np.mod(rose, 2 * np.pi))
    out["swing"] = swing
    heads["compass swing"] = swing.correct(heads["manufacturer"])
    # a field-domain fit cannot see a rotation about the vertical (A2 is only known up to one):
    # one reference heading -- the first compass-rose mark -- fixes it
    first = next(i for i, s_ in enumerate(rec.segment_slices()) if seg["manoeuvre"][i] == "compass_swing")
    s0 = rec.segment_slices()[first]
    psi0 = heading_from_field(e2.apply(m[s0, :2]), declination_rad=decl, frame="FLU")
    offset = float(np.angle(np.mean(np.exp(1j * (psi0 - seg["heading_set"][first])))))
    out["heading_offset_2d_deg"] = float(np.degrees(offset))
    heads["two-step 2-D + 1 reference heading"] = np.mod(heads["two-step 2-D"] - offset, 2 * np.pi)
    if psi_true is not None:
        out["heading_error_deg"] = {k: _err_stats(v, psi_true) for k, v in heads.items()}
        out["heading_series"] = {"time_s": rec.time_s[val], "true": psi_true, **heads}
    return sw


def _se_for(order, name, se, k):
    return float(se[k]) if k < len(se) else float("nan")


def _a2a2t_jacobian(e2) -> np.ndarray:
    """d(A2 A2')_{xx, xy, yy} / d(sx, sy, rho), A2 = [[sx, rho], [0, sy]]."""
    sx, sy, rho = (e2.params_[k] for k in ("sx", "sy", "rho"))
    order = list(e2.names_)[:3]
    J = {"sx": [2 * sx, 0, 0], "sy": [0, rho, 2 * sy], "rho": [2 * rho, sy, 0]}
    return np.array([J[n] for n in order]).T


def _row(name, unit, est, se, inj):
    z = None if inj is None or not se > 0 else float((est - inj) / se)
    return {"name": name, "unit": unit, "estimate": float(est), "std_error": float(se),
            "injected": None if inj is None else float(inj), "z": z,
            "within_bound": None if z is None else bool(abs(z) <= Z_BOUND)}


def _err_stats(psi, psi_true) -> dict:
    e = np.degrees(wrap_pi(np.asarray(psi) - psi_true))
    return {"mean": float(np.mean(e)), "rms": float(np.sqrt(np.mean(e**2))), "max_abs": float(np.max(np.abs(e)))}
