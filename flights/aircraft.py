"""The Cessna Citation II (model 550) in MuJoCo: aerodynamics, thrust, landing gear (its autopilot:
:mod:`imurig.flights.autopilot`).

MuJoCo integrates one free rigid body (``assets/citation.xml``) in a flat local-level world
whose axes are NED at the departure point (gravity +z, constant 9.81 m/s^2). Every physics step
computes, from the body's state of that step and the held control inputs,

    aerodynamic force and moment (stability derivatives, below) + thrust  -> xfrc_applied (CG)
    tyre forces on the three gear wheels (imurig.flights.vehicle.TyreModel) -> xfrc_applied (wheels)

so the short-period, phugoid, Dutch-roll, roll and spiral modes arise from the dynamics. A flight
runs these steps in compiled code between two control updates (:meth:`CitationSim.run`,
:mod:`imurig.flights.flight_kernel`; the same samples as :meth:`CitationSim.step`, the per-step
Python path kept for trim, linearisation and tests).
The Earth terms (rotation, transport rate, Coriolis, WGS-84 normal gravity) are added to the
recorded kinematics afterwards, exactly, in :mod:`imurig.flights.truth`.

Aerodynamic model (SI, angles in rad; q̄ = ρV²/2 with ISA density ρ(h); hats are the usual
non-dimensional rates p̂ = p b/2V, q̂ = q c/V, r̂ = r b/2V, α̇̂ = α̇ c/V):

    C_L = C_L0 + C_Lα α + C_Lq q̂ + C_Lα̇ α̇̂ + C_Lδe δe + C_Lflap f
    C_D = C_D0 + C_L² / (π A e) + C_Dflap f
    C_Y = C_Yβ β + C_Yp p̂ + C_Yr r̂ + C_Yδa δa + C_Yδr δr
    C_l = C_lβ β + C_lp p̂ + C_lr r̂ + C_lδa δa + C_lδr δr
    C_m = C_m0 + C_mα α + C_mq q̂ + C_mα̇ α̇̂ + C_mδe δe + C_mflap f
    C_n = C_nβ β + C_np p̂ + C_nr r̂ + C_nδa δa + C_nδr δr
    F_B = [−D cos α + L sin α + T, q̄ S C_Y, −D sin α − L cos α],  M_B = q̄ S [b C_l, c C_m, b C_n]

with L = q̄ S C_L, D = q̄ S C_D, T the thrust along body x (first-order spool-up). Source of
the numbers: the TU Delft Citation II flight-dynamics model used in the faculty's flight-test
course (public teaching data: C_Xu, C_Zα = −5.74, C_Zq = −5.66, C_mq = −8.79, C_mα̇ = +0.178,
C_mα = −0.56, C_mδe = −1.16, C_lp = −0.71, C_nβ = +0.135, C_nr = −0.206, ...; geometry
S = 30 m², c̄ = 2.0569 m, b = 15.911 m). The lift derivatives are taken as C_Lx = −C_Zx.
Sign conventions here: δe > 0 trailing edge down (nose down), δa > 0 rolls right (the Delft
C_lδa, C_nδa, C_Yδa with their sign flipped), δr > 0 trailing edge left (nose left).
Order-of-magnitude-correct values for a light business jet, not a certified model: no
compressibility, no stall (plans are validated to stay below C_L,max), no ground effect.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import mujoco
import numpy as np

from imurig.flights.vehicle import Cmd, TyreModel, VehicleSim, Wheel, quat_to_C
from imurig.rigs.mujoco_clock import untimed

__all__ = ["G0", "CitationAero", "CitationSim", "Cmd", "isa_density", "modes", "wall_clock"]

G0 = 9.81  # the flat world's gravity, m/s^2 (the truth uses WGS-84 normal gravity instead)
_NO_CONTACT = int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)
AIRBORNE_CLEARANCE_M = 10.0   # IMU height above the ground (plus 100 m/s of sink) beyond which no contact is sought


def isa_density(h_m: float) -> float:
    """ISA troposphere density, kg/m^3, at geopotential height h (m)."""
    return 1.225 * (1.0 - 2.25577e-5 * h_m) ** 4.2559


@dataclass(frozen=True)
class CitationAero:
    """Geometry, stability and control derivatives, engines and actuators (SI)."""

    S_m2: float = 30.0
    c_m: float = 2.0569
    b_m: float = 15.911
    CL0: float = 0.10
    CLa: float = 5.084
    CLq: float = 5.6629
    CLadot: float = 0.0035
    CLde: float = 0.69612
    CL_max: float = 1.25
    CD0: float = 0.04
    oswald: float = 0.8
    CL_flaps: float = 0.45
    CD_flaps: float = 0.025
    Cm0: float = 0.0297
    Cma: float = -0.5626
    Cmq: float = -8.79415
    Cmadot: float = 0.178
    Cmde: float = -1.1642
    Cm_flaps: float = -0.04
    CYb: float = -0.75
    CYp: float = -0.0304
    CYr: float = 0.8495
    CYda: float = 0.04
    CYdr: float = 0.23
    Clb: float = -0.1026
    Clp: float = -0.71085
    Clr: float = 0.2376
    Clda: float = 0.23088
    Cldr: float = 0.0344
    Cnb: float = 0.1348
    Cnp: float = -0.0602
    Cnr: float = -0.2061
    Cnda: float = 0.012
    Cndr: float = -0.0939
    thrust_max_N: float = 2 * 11_120.0      # two P&W JT15D-4, sea-level static
    engine_tau_s: float = 1.5
    surface_tau_s: float = 0.08
    de_limits_rad: tuple = (-0.30, 0.26)
    da_limit_rad: float = 0.35
    dr_limit_rad: float = 0.40
    steer_limit_rad: float = 1.0
    limit_load_factor: float = 3.0          # FAR 25.337 for ~13 300 lb gives 3.1
    r_cg_B_m: tuple = (-1.5, -0.3, 0.2)     # CG relative to the IMU (body origin), FRD

    @property
    def aspect_ratio(self) -> float:
        return self.b_m ** 2 / self.S_m2

    def thrust_max(self, h_m: float) -> float:
        return self.thrust_max_N * (isa_density(h_m) / 1.225) ** 0.75

    def forces(self, V, alpha, beta, adot, p, q, r, de, da, dr, thrust, flaps, rho):
        """Aerodynamic + thrust force (N) and moment about the CG (N m), body FRD, as 6 floats."""
        V = max(V, 1.0)
        qbar = 0.5 * rho * V * V
        S, c, b = self.S_m2, self.c_m, self.b_m
        ph, qh, rh, ah = p * b / (2 * V), q * c / V, r * b / (2 * V), adot * c / V
        CL = self.CL0 + self.CLa * alpha + self.CLq * qh + self.CLadot * ah + self.CLde * de + self.CL_flaps * flaps
        CD = self.CD0 + CL * CL / (math.pi * self.aspect_ratio * self.oswald) + self.CD_flaps * flaps
        CY = self.CYb * beta + self.CYp * ph + self.CYr * rh + self.CYda * da + self.CYdr * dr
        Cl = self.Clb * beta + self.Clp * ph + self.Clr * rh + self.Clda * da + self.Cldr * dr
        Cm = (self.Cm0 + self.Cma * alpha + self.Cmq * qh + self.Cmadot * ah + self.Cmde * de
              + self.Cm_flaps * flaps)
        Cn = self.Cnb * beta + self.Cnp * ph + self.Cnr * rh + self.Cnda * da + self.Cndr * dr
        L, D = qbar * S * CL, qbar * S * CD
        ca, sa = math.cos(alpha), math.sin(alpha)
        return (-D * ca + L * sa + thrust, qbar * S * CY, -D * sa - L * ca,
                qbar * S * b * Cl, qbar * S * c * Cm, qbar * S * b * Cn)


class CitationSim(VehicleSim):
    """The Citation: aerodynamics + thrust + gear, actuator and engine lags."""

    body_name = "aircraft"

    def __init__(self, aero: CitationAero | None = None, rate_hz: float = 100.0, substeps: int = 1,
                 h0_m: float = 0.0):
        self.aero = aero or CitationAero()
        main = TyreModel(cornering_stiffness_N_per_rad=150_000.0, mu=0.7, rolling_resistance=0.02)
        nose = TyreModel(cornering_stiffness_N_per_rad=60_000.0, mu=0.7, rolling_resistance=0.02)
        wheels = [Wheel("nose_gear", "nose_strut", 0.2, nose, steered=True, braked=False),
                  Wheel("main_gear_left", "main_strut_left", 0.3, main),
                  Wheel("main_gear_right", "main_strut_right", 0.3, main)]
        self.act = Cmd()                 # actual surface deflections / spool state
        self._alpha_prev = None
        self._kernel = None              # the compiled steps' parameter arrays (:meth:`run`)
        super().__init__("citation.xml", wheels, rate_hz, substeps, h0_m)

    def _update_state(self):
        s = super()._update_state()
        x, y, z = self.aero.r_cg_B_m
        s.u, s.v, s.w = self.body_velocity(x, y, z)
        s.V = math.sqrt(s.u * s.u + s.v * s.v + s.w * s.w)
        s.alpha = math.atan2(s.w, s.u) if s.V > 1.0 else 0.0
        s.beta = math.asin(max(-1.0, min(1.0, s.v / s.V))) if s.V > 1.0 else 0.0
        return s

    def _actuate(self, cmd: Cmd):
        a, act = self.aero, self.act
        ks = min(1.0, self.dt / a.surface_tau_s)
        ke = min(1.0, self.dt / a.engine_tau_s)
        act.de += ks * (max(a.de_limits_rad[0], min(a.de_limits_rad[1], cmd.de)) - act.de)
        act.da += ks * (max(-a.da_limit_rad, min(a.da_limit_rad, cmd.da)) - act.da)
        act.dr += ks * (max(-a.dr_limit_rad, min(a.dr_limit_rad, cmd.dr)) - act.dr)
        act.thr += ke * (max(0.0, min(1.0, cmd.thr)) - act.thr)
        act.steer = max(-a.steer_limit_rad, min(a.steer_limit_rad, cmd.steer))
        act.brake = max(0.0, min(1.0, cmd.brake))
        act.flaps += min(1.0, self.dt / 8.0) * (cmd.flaps - act.flaps)

    def body_forces(self, cmd: Cmd):
        s, a, act = self.s, self.aero, self.act
        adot = 0.0 if self._alpha_prev is None else (s.alpha - self._alpha_prev) * self.rate_hz * self.substeps
        self._alpha_prev = s.alpha
        return a.forces(s.V, s.alpha, s.beta, adot, s.p, s.q, s.r, act.de, act.da, act.dr,
                        act.thr * a.thrust_max(s.h), act.flaps, isa_density(s.h))

    def step(self, cmd: Cmd):
        self._actuate(cmd)
        super().step(self.act)

    def run(self, cmd: Cmd, n: int):
        """``n`` samples with ``cmd`` held: :meth:`step` ``n`` times, in compiled code
        (:mod:`imurig.flights.flight_kernel`: the same forces at every physics step, the same samples)."""
        if self._kernel is None:
            self._kernel = self._load_kernel()
        untimed()   # steps without MuJoCo's profiling clock (imurig.rigs.mujoco_clock): the same samples
        if self._kernel is False:
            for _ in range(n):
                self.step(cmd)
            return
        run_steps, io, md, rest, opt = self._kernel
        A = self.act
        io[:15] = (cmd.de, cmd.da, cmd.dr, cmd.thr, cmd.steer, cmd.brake, cmd.flaps,
                 A.de, A.da, A.dr, A.thr, A.steer, A.brake, A.flaps,
                 math.nan if self._alpha_prev is None else self._alpha_prev)
        block, i0 = self._reserve(n)
        s = self.s
        # far above the ground no wheel can touch it within the held interval: collision detection and the
        # (then empty) constraint solver off; they find nothing there, so the steps are the same, 5 % faster
        far = s.h - self.h0_m > AIRBORNE_CLEARANCE_M + 100.0 * n * self.dt
        if far:
            flags = opt.disableflags
            opt.disableflags = flags | _NO_CONTACT
        try:
            self.t = run_steps(*md, n, self.substeps, self.rate_hz, self.t, self.h0_m, *rest, block, i0)
        finally:
            if far:
                opt.disableflags = flags
        # the state as :meth:`_update_state` makes it, its trigonometry done by the kernel (io[7:42], one list)
        v = io[7:].tolist()
        A.de, A.da, A.dr, A.thr, A.steer, A.brake, A.flaps, prev = v[:8]
        self._alpha_prev = None if math.isnan(prev) else prev
        s.t = self.t
        s.C = tuple(v[8:17])
        s.phi, s.theta, s.psi, s.u, s.v, s.w, s.V, s.alpha, s.beta = v[17:26]
        s.pN, s.pE, s.pD, s.vN, s.vE, s.vD, s.p, s.q, s.r = v[26:35]
        s.h = self.h0_m - s.pD
        self._ground_track(s)

    def _load_kernel(self):
        """The compiled steps (:func:`imurig.flights.flight_kernel.run_steps`) with this aircraft's fixed
        arguments, or False without a MuJoCo library to link (the Python path then steps)."""
        # lazy: numba (0.3 CPU-s to import) only when a flight is flown, not when a plan is validated
        from imurig.flights import flight_kernel as fk

        if not fk.AVAILABLE:
            return False
        m, d = self.model, self.data
        rest = (self.bid, np.empty(fk.IO_SIZE), fk.aero_params(self.aero), fk.wheel_params(self.wheels),
                float(self.drive_force_N), int(self.n_driven))
        return fk.run_steps, rest[1], (m._address, d._address, d.qpos, d.qvel, d.xfrc_applied), rest, m.opt

    # ------------------------------------------------------------ trim / linearise
    def _place(self, V, h_m, alpha, theta, psi=0.0, phi=0.0, w_B=(0.0, 0.0, 0.0), v_side=0.0):
        """Put the body at (0, 0, h) with attitude (φ, θ, ψ), the CG moving at V with angle of
        attack α and side velocity v_side (body axes), body rates w_B; gear at its free hang."""
        d, a = self.data, self.aero
        cr, sr = math.cos(phi / 2), math.sin(phi / 2)
        cp, sp = math.cos(theta / 2), math.sin(theta / 2)
        cy, sy = math.cos(psi / 2), math.sin(psi / 2)
        q = np.array([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                      cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy])
        d.qpos[:] = self.model.qpos0
        d.qpos[0:3] = (0.0, 0.0, self.h0_m - h_m)
        d.qpos[3:7] = q
        d.qvel[:] = 0.0
        for _, b, qa, _, k, _, _ in self.wheels:
            d.qpos[qa] = float(self.model.body_mass[b]) * G0 / k
        cg = np.array(a.r_cg_B_m)
        w_B = np.asarray(w_B, float)
        Cnb = np.array(quat_to_C(*q)).reshape(3, 3)
        ub = math.sqrt(max(V * V - v_side * v_side, 0.0))
        v_cg_B = np.array([ub * math.cos(alpha), v_side, ub * math.sin(alpha)])
        d.qvel[0:3] = Cnb @ (v_cg_B - np.cross(w_B, cg))
        d.qvel[3:6] = w_B
        d.xfrc_applied[:] = 0.0
        mujoco.mj_forward(self.model, d)
        self._update_state()
        return Cnb, v_cg_B, w_B

    def _accelerations(self, de, da, dr, thrust, adot=0.0):
        """Apply the aerodynamic forces of the current state; return (CG acceleration in body
        axes minus ω×v, i.e. the body-axis velocity derivative (3,), body angular acceleration (3,))."""
        d, a, s = self.data, self.aero, self.s
        f = a.forces(s.V, s.alpha, s.beta, adot, s.p, s.q, s.r, de, da, dr, thrust, 0.0, isa_density(s.h))
        C = s.C
        d.xfrc_applied[self.bid] = (
            C[0] * f[0] + C[1] * f[1] + C[2] * f[2], C[3] * f[0] + C[4] * f[1] + C[5] * f[2],
            C[6] * f[0] + C[7] * f[1] + C[8] * f[2], C[0] * f[3] + C[1] * f[4] + C[2] * f[5],
            C[3] * f[3] + C[4] * f[4] + C[5] * f[5], C[6] * f[3] + C[7] * f[4] + C[8] * f[5])
        mujoco.mj_forward(self.model, d)
        Cnb = np.array(C).reshape(3, 3)
        cg = np.array(a.r_cg_B_m)
        w_B = np.array([s.p, s.q, s.r])
        wdot = d.qacc[3:6].copy()
        a_cg_N = d.qacc[0:3] + Cnb @ (np.cross(wdot, cg) + np.cross(w_B, np.cross(w_B, cg)))
        v_cg_B = np.array([s.u, s.v, s.w])
        return Cnb.T @ a_cg_N - np.cross(w_B, v_cg_B), wdot

    def set_airborne(self, V: float, h_m: float, psi: float = 0.0, gamma: float = 0.0):
        """Place the aircraft in trimmed wings-level flight: (α, δe, T) solved by Newton on the
        simulated accelerations (MuJoCo forward pass, gear masses included) to 1e-9."""
        a = self.aero
        x = np.array([0.03, 0.0, 0.3 * a.thrust_max(h_m)])

        def resid(x):
            self._place(V, h_m, x[0], x[0] + gamma, psi)
            vdot, wdot = self._accelerations(x[1], 0.0, 0.0, x[2])
            return np.array([vdot[0], vdot[2], wdot[1]])

        for _ in range(30):
            r0 = resid(x)
            if np.max(np.abs(r0)) < 1e-9:
                break
            J = np.empty((3, 3))
            for i, hstep in enumerate((1e-6, 1e-6, 1e-2)):
                xp = x.copy()
                xp[i] += hstep
                J[:, i] = (resid(xp) - r0) / hstep
            x = x - np.linalg.solve(J, r0)
        alpha, de, T = (float(v) for v in x)
        self._place(V, h_m, alpha, alpha + gamma, psi)
        self.data.xfrc_applied[:] = 0.0
        self.act = Cmd(de=de, thr=T / a.thrust_max(h_m))
        self._alpha_prev = alpha
        return {"alpha": alpha, "de": de, "thrust_N": T, "theta": alpha + gamma, "residual": r0.tolist()}

    def linearise(self, V: float, h_m: float, eps: float = 1e-5) -> dict:
        """Central-difference Jacobian of the simulated dynamics about trimmed level flight.

        States: longitudinal x = [u, w, q, θ] (CG velocity in body axes m/s, rad/s, rad),
        lateral x = [v, p, r, φ]. Each column perturbs the MuJoCo state, applies the
        aerodynamic forces of that state, runs one forward pass and reads qacc. The gear
        struts are locked (their modes are at 50 rad/s, far above the flight modes).
        The α̇ terms enter as ẋ = (I − b cᵀ)⁻¹ A x with α̇ = cᵀ ẋ.
        """
        trim = self.set_airborne(V, h_m)
        de, T = trim["de"], trim["thrust_N"]
        # struts locked (huge armature on their slide joints): at the flight modes' frequencies the
        # stiff gear (50 rad/s) moves with the airframe, so the wheels count as rigid mass
        arm = self.model.dof_armature.copy()
        for _, _, _, dadr, _, _, _ in self.wheels:
            self.model.dof_armature[dadr] = 1e12
        th0, al0 = trim["theta"], trim["alpha"]

        def f(xlon, xlat, adot=0.0):
            u, w, q, th = xlon
            v, p, r, ph = xlat
            Vt = math.sqrt(u * u + v * v + w * w)
            self._place(Vt, h_m, math.atan2(w, u), th, 0.0, ph, (p, q, r), v_side=v)
            vdot, wdot = self._accelerations(de, 0.0, 0.0, T, adot)
            phidot = p + (q * math.sin(ph) + r * math.cos(ph)) * math.tan(th)
            thdot = q * math.cos(ph) - r * math.sin(ph)
            return (np.array([vdot[0], vdot[2], wdot[1], thdot]), np.array([vdot[1], wdot[0], wdot[2], phidot]))

        x0lon = np.array([V * math.cos(al0), V * math.sin(al0), 0.0, th0])
        x0lat = np.zeros(4)
        f0lon, f0lat = f(x0lon, x0lat)
        Alon, Alat = np.empty((4, 4)), np.empty((4, 4))
        for i in range(4):
            dx = np.zeros(4)
            dx[i] = eps * (V if i < 2 else 1.0)
            Alon[:, i] = (f(x0lon + dx, x0lat)[0] - f(x0lon - dx, x0lat)[0]) / (2 * dx[i])
            dy = np.zeros(4)
            dy[i] = eps * (V if i == 0 else 1.0)
            Alat[:, i] = (f(x0lon, x0lat + dy)[1] - f(x0lon, x0lat - dy)[1]) / (2 * dy[i])
        b = (f(x0lon, x0lat, 1e-4)[0] - f(x0lon, x0lat, -1e-4)[0]) / 2e-4
        u0, w0 = x0lon[0], x0lon[1]
        c_ad = np.array([-w0, u0, 0.0, 0.0]) / (u0 ** 2 + w0 ** 2)   # α̇ = c·ẋ
        Alon = np.linalg.solve(np.eye(4) - np.outer(b, c_ad), Alon)
        self.model.dof_armature[:] = arm
        self.set_airborne(V, h_m)
        return {"A_lon": Alon, "A_lat": Alat, "trim": trim, "residual_lon": f0lon[:3].tolist(),
                "residual_lat": f0lat.tolist(), "mass_kg": float(self.model.body_subtreemass[self.bid])}


def modes(A_lon: np.ndarray, A_lat: np.ndarray) -> dict:
    """Eigen-modes: short period and phugoid (oscillatory pairs of A_lon by frequency), Dutch
    roll (oscillatory pair of A_lat), roll and spiral (real roots of A_lat, fast and slow).
    Each as natural frequency (rad/s), damping ratio, period (s) or time constant (s)."""
    def osc(ev):
        wn = abs(ev)
        return {"omega_n_rad_s": float(wn), "zeta": float(-ev.real / wn), "period_s": float(2 * math.pi / abs(ev.imag))}

    lon = np.linalg.eigvals(A_lon)
    pairs = sorted([e for e in lon if e.imag > 1e-9], key=abs)
    lat = np.linalg.eigvals(A_lat)
    dr = [e for e in lat if e.imag > 1e-9]
    real = sorted([e.real for e in lat if abs(e.imag) <= 1e-9], key=abs)
    out = {"eig_lon": lon.tolist(), "eig_lat": lat.tolist()}
    if len(pairs) == 2:
        out["phugoid"], out["short_period"] = osc(pairs[0]), osc(pairs[1])
    if dr:
        out["dutch_roll"] = osc(dr[0])
    if len(real) == 2:
        out["spiral"] = {"eigenvalue": float(real[0]), "time_constant_s": float(-1 / real[0]) if real[0] else math.inf}
        out["roll"] = {"eigenvalue": float(real[1]), "time_constant_s": float(-1 / real[1])}
    return out


def wall_clock() -> float:
    return time.perf_counter()
