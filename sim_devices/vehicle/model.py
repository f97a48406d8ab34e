"""Nonlinear single-track vehicle model with roll, load transfer and magic-formula tyres.

States: CG position (east, north), yaw ψ, CG velocity in vehicle axes (v_x, v_y), yaw rate r,
roll φ and roll rate, plus the steering-wheel angle. Equations (ISO 8855 axes):

- planar: m(v̇_x − r v_y) = ΣF_x,  m(v̇_y + r v_x) = ΣF_y,  I_z ṙ = ΣM_z. The lateral tyre force of
  an axle is evaluated at the axle's single-track slip angle but for each of its two wheels at
  that wheel's vertical load, so lateral load transfer lowers the axle's cornering stiffness and
  peak force (load-sensitive magic formula, see :mod:`sim_devices.vehicle.tyre`).
- roll about the roll axis, driven by the planar lateral acceleration a_y = v̇_y + r v_x:
  I_φ φ̈ = m h′(a_y cos φ + g sin φ) − (K_φf + K_φr) φ − C_φ φ̇, with h′ the CG height above the
  roll axis. Roll does not feed back into the planar equations except through the wheel loads.
- wheel loads: static + longitudinal transfer m a_x h / L + lateral transfer per axle
  (m a_y·(axle share)·h_roll-axis + K_φ,axle φ + C_φ,axle φ̇)/track. The damper moment is split
  like the springs. Loads are clipped at zero per wheel with the axle total kept, so the sum is
  always the weight and the LTR reaches exactly ±1 when both inside wheels have lifted (the
  model does not roll over).
- at very low speed the slip-angle equations become stiff and undefined at v_x = 0; below
  |v_x| = 0.6 m/s the lateral states are blended into a kinematic model (v_y = b r, r = v_x tanδ/L,
  reached with a 20 ms lag), fully kinematic below 0.3 m/s. This handles stopping and reversing.

Integration: semi-implicit Euler at a fixed step of at most 1 ms on plain Python floats (one
force evaluation per step; the steady states are exact and the 1 ms step resolves the ~2 Hz roll
and yaw modes). Wheel loads inside a step use the accelerations of the previous step (1 ms lag).
The speed controller and steering actuator run inside the loop; closed-loop steering
controllers (drivers) are called every 5 ms.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import numpy.typing as npt

from sim_devices.vehicle.params import GRAVITY, VehicleParams
from sim_devices.vehicle.steering import SteeringGear
from sim_devices.vehicle.tyre import axle_tyres
from vsccore.errors import SimulationError

__all__ = [
    "DRIVER_PERIOD_S",
    "MAX_STEP_S",
    "Phase",
    "SpeedProfile",
    "SteeringController",
    "SwaProfile",
    "VehicleState",
    "wheel_loads",
    "wheel_long_forces",
]

FloatArray = npt.NDArray[np.float64]

MAX_STEP_S = 1e-3
"""Largest integration step (s); output rates below 1 kHz are sub-stepped."""
DRIVER_PERIOD_S = 5e-3
"""Update period of closed-loop steering controllers (s)."""
V_KIN_LO = 0.3
"""Below this |v_x| (m/s) the lateral states follow the kinematic model only."""
V_KIN_HI = 0.6
"""Above this |v_x| (m/s) the dynamic (tyre-force) model alone is used."""
TAU_KIN = 0.02
"""Lag (s) with which the lateral states reach their kinematic values at low speed."""
STEER_LAG_S = 0.04
"""Time constant of the steering actuator under closed-loop control (s)."""
STEER_RATE_MAX = math.radians(1200.0)
"""Steering-wheel rate limit under closed-loop control (rad/s)."""
AIR_DENSITY = 1.2
"""Air density (kg/m³)."""
_SPEED_KP = 1.5
_SPEED_KI = 0.4
_SPEED_INT_MAX = 3.0
_DRIVE_ACCEL_MAX = 4.5
_BRAKE_DECEL_MAX = 10.0
_V_SMOOTH = 0.02  # rolling resistance fades in over ±2 cm/s instead of switching sign at standstill


@dataclass(frozen=True, slots=True)
class VehicleState:
    """Snapshot of the vehicle handed to drivers and scenarios (SI, ISO 8855)."""

    t: float
    east: float
    north: float
    yaw: float
    vx: float
    vy: float
    yaw_rate: float
    roll: float
    swa: float


class SteeringController(Protocol):
    """A closed-loop driver: called every :data:`DRIVER_PERIOD_S` with the state, returns a SWA target.

    Setting ``done`` ends the phase early (the state at that moment is kept).
    """

    done: bool

    def update(self, state: VehicleState) -> float:
        """Steering-wheel angle target (rad) for the current state."""
        ...


SpeedProfile = Callable[[FloatArray], tuple[FloatArray, FloatArray]]
"""Phase time (s) → (speed target v_x in m/s, feed-forward acceleration in m/s²), vectorised."""
SwaProfile = Callable[[FloatArray], FloatArray]
"""Phase time (s) → steering-wheel angle (rad), vectorised (a steering robot)."""


@dataclass(frozen=True, slots=True)
class Phase:
    """One stretch of a drive: a speed command and either an open-loop SWA or a steering controller."""

    duration_s: float
    """Length of the phase (s); the maximum if the controller may finish early."""
    speed: SpeedProfile | None
    """Speed target; None releases the throttle (coasting)."""
    swa: SwaProfile | None = None
    controller: SteeringController | None = None
    label: str = ""
    meta: dict[str, float | str] = field(default_factory=dict)
    """Extra facts about the phase for GroundTruth.meta (e.g. a course origin)."""

    def __post_init__(self) -> None:
        if (self.swa is None) == (self.controller is None):
            raise SimulationError(f"phase {self.label!r}: give exactly one of an SWA profile or a controller")
        if not math.isfinite(self.duration_s) or self.duration_s < 0.0:
            raise SimulationError(f"phase {self.label!r}: duration must be finite and >= 0, got {self.duration_s}")


@dataclass(slots=True)
class DynState:
    """Mutable integrator state (plain floats)."""

    step: int = 0
    east: float = 0.0
    north: float = 0.0
    yaw: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    yaw_rate: float = 0.0
    roll: float = 0.0
    roll_rate: float = 0.0
    swa: float = 0.0
    swa_target: float = 0.0
    ax_prev: float = 0.0
    ay_prev: float = 0.0
    speed_int: float = 0.0
    out_count: int = 0
    drv_count: int = 0

    def snapshot(self, dt: float) -> VehicleState:
        return VehicleState(
            t=self.step * dt,
            east=self.east,
            north=self.north,
            yaw=self.yaw,
            vx=self.vx,
            vy=self.vy,
            yaw_rate=self.yaw_rate,
            roll=self.roll,
            swa=self.swa,
        )


@dataclass(slots=True)
class Recorder:
    """Output samples as plain lists (one entry per output sample)."""

    east: list[float] = field(default_factory=list)
    north: list[float] = field(default_factory=list)
    yaw: list[float] = field(default_factory=list)
    vx: list[float] = field(default_factory=list)
    vy: list[float] = field(default_factory=list)
    yaw_rate: list[float] = field(default_factory=list)
    ax: list[float] = field(default_factory=list)
    ay: list[float] = field(default_factory=list)
    roll: list[float] = field(default_factory=list)
    roll_rate: list[float] = field(default_factory=list)
    swa: list[float] = field(default_factory=list)
    delta: list[float] = field(default_factory=list)
    fx: list[float] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.east)

    def arrays(self) -> dict[str, FloatArray]:
        return {name: np.asarray(getattr(self, name), dtype=np.float64) for name in self.__slots__}


class Integrator:
    """Fixed-step integrator of one vehicle; :meth:`run` advances a :class:`DynState` through a phase."""

    def __init__(self, params: VehicleParams, gear: SteeringGear, rate_hz: float) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise SimulationError(f"output rate must be a positive number of Hz, got {rate_hz!r}")
        self.params = params
        self.gear = gear
        self.rate_hz = float(rate_hz)
        self.n_sub = max(1, math.ceil(1.0 / (rate_hz * MAX_STEP_S) - 1e-9))
        self.dt = 1.0 / (rate_hz * self.n_sub)
        self.driver_every = max(1, round(DRIVER_PERIOD_S / self.dt))

    def run(self, st: DynState, phase: Phase, rec: Recorder) -> None:
        """Advance ``st`` through ``phase``, appending every ``n_sub``-th step to ``rec``."""
        p = self.params
        dt = self.dt
        n = round(phase.duration_s / dt)
        if n <= 0:
            return
        tau = np.arange(n, dtype=np.float64) * dt
        lock = self.gear.lock_swa
        coast = phase.speed is None
        vref: list[float] = []
        aff: list[float] = []
        if phase.speed is not None:
            v_arr, a_arr = phase.speed(tau)
            vref = np.broadcast_to(np.asarray(v_arr, dtype=float), (n,)).tolist()
            aff = np.broadcast_to(np.asarray(a_arr, dtype=float), (n,)).tolist()
        ctrl = phase.controller
        swa_ol: list[float] = []
        if phase.swa is not None:
            swa_arr = np.broadcast_to(np.asarray(phase.swa(tau), dtype=float), (n,))
            if not np.all(np.isfinite(swa_arr)):
                raise SimulationError(f"phase {phase.label!r}: steering profile is not finite")
            swa_ol = np.clip(swa_arr, -lock, lock).tolist()
        if not coast and not (np.all(np.isfinite(vref)) and np.all(np.isfinite(aff))):
            raise SimulationError(f"phase {phase.label!r}: speed profile is not finite")

        # ---- constants as locals ------------------------------------------------------------
        sin, cos, atan, atan2, sqrt = math.sin, math.cos, math.atan, math.atan2, math.sqrt
        g = GRAVITY
        m = p.mass_kg
        inv_m = 1.0 / m
        inv_iz = 1.0 / p.yaw_inertia_kgm2
        inv_ixx = 1.0 / p.roll_inertia_kgm2
        a = p.cg_to_front_axle_m
        b = p.cg_to_rear_axle_m
        L = a + b
        htf = 0.5 * p.track_front_m
        htr = 0.5 * p.track_rear_m
        inv_tf = 1.0 / p.track_front_m
        inv_tr = 1.0 / p.track_rear_m
        W = m * g
        Wf0 = W * b / L
        kL = m * p.cg_height_m / L
        hp = p.cg_height_m - p.roll_axis_height_m
        mhp = m * hp
        kdf = m * (b / L) * p.roll_axis_height_m
        kdr = m * (a / L) * p.roll_axis_height_m
        Kf = p.roll_stiffness_front_nm_per_rad
        Kr = p.roll_stiffness_rear_nm_per_rad
        Kphi = Kf + Kr
        Cphi = p.roll_damping_nms_per_rad
        Cf_ = Cphi * Kf / Kphi
        Cr_ = Cphi * Kr / Kphi
        frr = p.rolling_resistance_coeff * W
        kaero = 0.5 * AIR_DENSITY * p.drag_area_m2
        drive_f = p.drive_share_front
        brake_f = p.brake_share_front
        fmax = m * _DRIVE_ACCEL_MAX
        fmin = -m * _BRAKE_DECEL_MAX
        tf_, tr_ = axle_tyres(p)
        Cc = p.tyre_shape_c
        Ee = p.tyre_curvature_e
        mu0 = p.tyre_peak_mu
        eps = p.tyre_mu_load_sensitivity
        mu_floor = 0.1 * mu0
        # μ(F_z) = mu_a − mu_k·F_z ; B = b_num/((1 + (x_k F_z)²)·μ)
        mu_af, mu_kf = mu0 * (1.0 + eps), mu0 * eps / tf_.fz0
        mu_ar, mu_kr = mu0 * (1.0 + eps), mu0 * eps / tr_.fz0
        xkf = 1.0 / (tf_.stiffness_peak_ratio * tf_.fz0)
        xkr = 1.0 / (tr_.stiffness_peak_ratio * tr_.fz0)
        bnf = tf_.c_alpha0 * 2.0 * xkf / (tf_.stiffness_norm * Cc)
        bnr = tr_.c_alpha0 * 2.0 * xkr / (tr_.stiffness_norm * Cc)
        g0 = self.gear.grid_start
        ginv = self.gear.grid_inv_step
        gv = self.gear.grid_values
        gmax = len(gv) - 2
        inv_tauk = 1.0 / TAU_KIN
        inv_vband = 1.0 / (V_KIN_HI - V_KIN_LO)
        k_act = min(1.0, dt / STEER_LAG_S)
        max_dsw = STEER_RATE_MAX * dt
        drv_every = self.driver_every
        n_sub = self.n_sub

        # ---- state as locals ----------------------------------------------------------------
        step = st.step
        E, N, psi = st.east, st.north, st.yaw
        vx, vy, r = st.vx, st.vy, st.yaw_rate
        phi, phid = st.roll, st.roll_rate
        swa, swa_target = st.swa, st.swa_target
        ax_p, ay_p = st.ax_prev, st.ay_prev
        vint = st.speed_int
        out_count = st.out_count
        drv_count = st.drv_count

        rE, rN, rpsi = rec.east.append, rec.north.append, rec.yaw.append
        rvx, rvy, rr = rec.vx.append, rec.vy.append, rec.yaw_rate.append
        rax, ray = rec.ax.append, rec.ay.append
        rphi, rphid = rec.roll.append, rec.roll_rate.append
        rswa, rdelta, rfx = rec.swa.append, rec.delta.append, rec.fx.append

        for k in range(n):
            # ---- steering ------------------------------------------------------------------
            if ctrl is None:
                swa = swa_ol[k]
            else:
                if drv_count <= 0:
                    swa_target = ctrl.update(
                        VehicleState(
                            t=step * dt, east=E, north=N, yaw=psi, vx=vx, vy=vy, yaw_rate=r, roll=phi, swa=swa
                        )
                    )
                    if ctrl.done:
                        break
                    if swa_target > lock:
                        swa_target = lock
                    elif swa_target < -lock:
                        swa_target = -lock
                    drv_count = drv_every
                drv_count -= 1
                d_sw = (swa_target - swa) * k_act
                if d_sw > max_dsw:
                    d_sw = max_dsw
                elif d_sw < -max_dsw:
                    d_sw = -max_dsw
                swa += d_sw
            xg = (swa - g0) * ginv
            ig = int(xg)
            if ig < 0:
                ig = 0
            elif ig > gmax:
                ig = gmax
            v0 = gv[ig]
            delta = v0 + (xg - ig) * (gv[ig + 1] - v0)
            cd = cos(delta)
            sd = sin(delta)

            # ---- wheel loads (accelerations of the previous step) ---------------------------
            Fzf = Wf0 - kL * ax_p
            if Fzf < 0.0:
                Fzf = 0.0
            elif Fzf > W:
                Fzf = W
            hf = 0.5 * Fzf
            hr = 0.5 * (W - Fzf)
            dF = (kdf * ay_p + Kf * phi + Cf_ * phid) * inv_tf
            if dF > hf:
                dF = hf
            elif dF < -hf:
                dF = -hf
            dR = (kdr * ay_p + Kr * phi + Cr_ * phid) * inv_tr
            if dR > hr:
                dR = hr
            elif dR < -hr:
                dR = -hr
            Fz_fl = hf - dF
            Fz_fr = hf + dF
            Fz_rl = hr - dR
            Fz_rr = hr + dR

            # ---- longitudinal: resistances, speed controller, force split -------------------
            avx = vx if vx >= 0.0 else -vx
            F_res = frr * vx / (avx + _V_SMOOTH) + kaero * vx * avx
            if coast:
                Fx = 0.0
            else:
                e_v = vref[k] - vx
                vint += e_v * dt
                if vint > _SPEED_INT_MAX:
                    vint = _SPEED_INT_MAX
                elif vint < -_SPEED_INT_MAX:
                    vint = -_SPEED_INT_MAX
                Fx = m * (aff[k] + _SPEED_KP * e_v + _SPEED_KI * vint) + F_res
                if Fx > fmax:
                    Fx = fmax
                elif Fx < fmin:
                    Fx = fmin
            sf = drive_f if Fx * vx >= 0.0 else brake_f
            fxf = 0.5 * sf * Fx
            fxr = 0.5 * Fx - fxf

            # ---- tyres ------------------------------------------------------------------------
            # Per wheel: μ(F_z), D = μF_z, friction-limited F_x, magic-formula F_y, friction ellipse.
            mu = mu_af - mu_kf * Fz_fl
            mu = mu if mu > mu_floor else mu_floor
            D_fl = mu * Fz_fl
            mu_fl = mu
            mu = mu_af - mu_kf * Fz_fr
            mu = mu if mu > mu_floor else mu_floor
            D_fr = mu * Fz_fr
            mu_fr = mu
            mu = mu_ar - mu_kr * Fz_rl
            mu = mu if mu > mu_floor else mu_floor
            D_rl = mu * Fz_rl
            mu_rl = mu
            mu = mu_ar - mu_kr * Fz_rr
            mu = mu if mu > mu_floor else mu_floor
            D_rr = mu * Fz_rr
            mu_rr = mu
            Fx_fl = fxf if fxf <= D_fl else D_fl
            Fx_fl = Fx_fl if Fx_fl >= -D_fl else -D_fl
            Fx_fr = fxf if fxf <= D_fr else D_fr
            Fx_fr = Fx_fr if Fx_fr >= -D_fr else -D_fr
            Fx_rl = fxr if fxr <= D_rl else D_rl
            Fx_rl = Fx_rl if Fx_rl >= -D_rl else -D_rl
            Fx_rr = fxr if fxr <= D_rr else D_rr
            Fx_rr = Fx_rr if Fx_rr >= -D_rr else -D_rr

            w = (avx - V_KIN_LO) * inv_vband
            if w > 0.0:
                vyf = vy + a * r
                vxw = vx * cd + vyf * sd
                vyw = vyf * cd - vx * sd
                al_f = atan2(vyw, vxw if vxw >= 0.0 else -vxw)
                al_r = atan2(vy - b * r, avx)
                Fy_fl = Fy_fr = Fy_rl = Fy_rr = 0.0
                if D_fl > 0.0:
                    xz = xkf * Fz_fl
                    ba = bnf / ((1.0 + xz * xz) * mu_fl) * al_f
                    Fy_fl = -D_fl * sin(Cc * atan(ba - Ee * (ba - atan(ba))))
                    if Fx_fl != 0.0:
                        q = Fx_fl / D_fl
                        Fy_fl *= sqrt(1.0 - q * q)
                if D_fr > 0.0:
                    xz = xkf * Fz_fr
                    ba = bnf / ((1.0 + xz * xz) * mu_fr) * al_f
                    Fy_fr = -D_fr * sin(Cc * atan(ba - Ee * (ba - atan(ba))))
                    if Fx_fr != 0.0:
                        q = Fx_fr / D_fr
                        Fy_fr *= sqrt(1.0 - q * q)
                if D_rl > 0.0:
                    xz = xkr * Fz_rl
                    ba = bnr / ((1.0 + xz * xz) * mu_rl) * al_r
                    Fy_rl = -D_rl * sin(Cc * atan(ba - Ee * (ba - atan(ba))))
                    if Fx_rl != 0.0:
                        q = Fx_rl / D_rl
                        Fy_rl *= sqrt(1.0 - q * q)
                if D_rr > 0.0:
                    xz = xkr * Fz_rr
                    ba = bnr / ((1.0 + xz * xz) * mu_rr) * al_r
                    Fy_rr = -D_rr * sin(Cc * atan(ba - Ee * (ba - atan(ba))))
                    if Fx_rr != 0.0:
                        q = Fx_rr / D_rr
                        Fy_rr *= sqrt(1.0 - q * q)
            else:
                Fy_fl = Fy_fr = Fy_rl = Fy_rr = 0.0

            # ---- body forces and derivatives ---------------------------------------------------
            Fxw_f = Fx_fl + Fx_fr
            Fyw_f = Fy_fl + Fy_fr
            Fy_front = Fxw_f * sd + Fyw_f * cd
            Fxb = Fxw_f * cd - Fyw_f * sd + Fx_rl + Fx_rr - F_res
            Fyb = Fy_front + Fy_rl + Fy_rr
            Mz = (
                a * Fy_front
                - b * (Fy_rl + Fy_rr)
                + htf * ((Fx_fr - Fx_fl) * cd - (Fy_fr - Fy_fl) * sd)
                + htr * (Fx_rr - Fx_rl)
            )
            vxd = Fxb * inv_m + r * vy
            if w >= 1.0:
                vyd = Fyb * inv_m - r * vx
                rd = Mz * inv_iz
            else:
                # Low speed: pull v_y and r towards the kinematic (no-slip) values.
                rk = vx * sd / (cd * L)
                vyd_k = (b * rk - vy) * inv_tauk
                rd_k = (rk - r) * inv_tauk
                if w > 0.0:
                    vyd = w * (Fyb * inv_m - r * vx) + (1.0 - w) * vyd_k
                    rd = w * Mz * inv_iz + (1.0 - w) * rd_k
                else:
                    vyd = vyd_k
                    rd = rd_k
            ax = vxd - r * vy
            ay = vyd + r * vx
            phidd = (mhp * (ay * cos(phi) + g * sin(phi)) - Kphi * phi - Cphi * phid) * inv_ixx

            # ---- output -------------------------------------------------------------------------
            if out_count <= 0:
                rE(E)
                rN(N)
                rpsi(psi)
                rvx(vx)
                rvy(vy)
                rr(r)
                rax(ax)
                ray(ay)
                rphi(phi)
                rphid(phid)
                rswa(swa)
                rdelta(delta)
                rfx(Fx)
                out_count = n_sub
            out_count -= 1

            # ---- semi-implicit Euler ------------------------------------------------------------
            vx += vxd * dt
            vy += vyd * dt
            r += rd * dt
            phid += phidd * dt
            phi += phid * dt
            psi += r * dt
            cpsi = cos(psi)
            spsi = sin(psi)
            E += (vx * cpsi - vy * spsi) * dt
            N += (vx * spsi + vy * cpsi) * dt
            ax_p = ax
            ay_p = ay
            step += 1

        if not (math.isfinite(vx) and math.isfinite(vy) and math.isfinite(r) and math.isfinite(phi)):
            raise SimulationError(f"phase {phase.label!r}: the vehicle state became non-finite at t={step * dt:.3f} s")
        st.step = step
        st.east, st.north, st.yaw = E, N, psi
        st.vx, st.vy, st.yaw_rate = vx, vy, r
        st.roll, st.roll_rate = phi, phid
        st.swa, st.swa_target = swa, swa_target
        st.ax_prev, st.ay_prev = ax_p, ay_p
        st.speed_int = vint
        st.out_count = out_count
        st.drv_count = drv_count


def wheel_loads(
    params: VehicleParams, ax: FloatArray, ay: FloatArray, roll: FloatArray, roll_rate: FloatArray
) -> FloatArray:
    """Vertical wheel loads (n, 4) FL FR RL RR (N) for the given accelerations and roll motion.

    Same formula as the integrator (see the module docstring); loads are clipped at zero per
    wheel with the axle total kept, so each row sums to the weight.
    """
    p = params
    ax = np.asarray(ax, dtype=float)
    ay = np.asarray(ay, dtype=float)
    roll = np.asarray(roll, dtype=float)
    roll_rate = np.asarray(roll_rate, dtype=float)
    W = p.weight_n
    L = p.wheelbase_m
    a, b = p.cg_to_front_axle_m, p.cg_to_rear_axle_m
    m = p.mass_kg
    hr = p.roll_axis_height_m
    kphi = p.roll_stiffness_front_nm_per_rad + p.roll_stiffness_rear_nm_per_rad
    cf = p.roll_damping_nms_per_rad * p.roll_stiffness_front_nm_per_rad / kphi
    cr = p.roll_damping_nms_per_rad * p.roll_stiffness_rear_nm_per_rad / kphi
    fzf = np.clip(W * b / (a + b) - m * p.cg_height_m / L * ax, 0.0, W)
    half_f = 0.5 * fzf
    half_r = 0.5 * (W - fzf)
    d_f = (m * (b / (a + b)) * hr * ay + p.roll_stiffness_front_nm_per_rad * roll + cf * roll_rate) / p.track_front_m
    d_r = (m * (a / (a + b)) * hr * ay + p.roll_stiffness_rear_nm_per_rad * roll + cr * roll_rate) / p.track_rear_m
    d_f = np.clip(d_f, -half_f, half_f)
    d_r = np.clip(d_r, -half_r, half_r)
    return np.stack([half_f - d_f, half_f + d_f, half_r - d_r, half_r + d_r], axis=-1)


def wheel_long_forces(params: VehicleParams, fx_total: FloatArray, vx: FloatArray, loads: FloatArray) -> FloatArray:
    """Longitudinal tyre forces (n, 4) from the total drive/brake force, split and friction-limited as in the loop."""
    fx_total = np.asarray(fx_total, dtype=float)
    vx = np.asarray(vx, dtype=float)
    front, rear = axle_tyres(params)
    share = np.where(fx_total * vx >= 0.0, params.drive_share_front, params.brake_share_front)
    fxf = 0.5 * share * fx_total
    fxr = 0.5 * fx_total - fxf
    demand = np.stack([fxf, fxf, fxr, fxr], axis=-1)
    mu = np.stack(
        [front.mu(loads[:, 0]), front.mu(loads[:, 1]), rear.mu(loads[:, 2]), rear.mu(loads[:, 3])], axis=-1
    )
    limit = mu * loads
    return np.asarray(np.clip(demand, -limit, limit), dtype=float)
