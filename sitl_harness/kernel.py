"""The compiled inner loop: controller at its rate, plant RK4 at the physics rate.

`advance` runs `n` physics steps in place with the controller executed every `decim` steps (the
controller sees the true state: the SITL models a perfect estimator). `VehicleModel` wraps the
arrays for Python callers.

Actuator (command) delay: with `delay_steps` = N > 0 the rotor-speed commands reach the motors N
physics steps after the controller computed them (a FIFO of N commands: ESC/bus transport, the
"larger actuator delay" of a real aircraft, a truth property its vehicle file does not know). N = 0
(the default) is the direct path, unchanged.
"""

from __future__ import annotations

import math

import numpy as np

from contracts.vehicle import SITL_KEYS, G

from contracts.jit import njit
from .control import (C_ATT_P, C_DT, C_HTE_TAU, C_IDLE, C_N, C_POS_P, C_RATE_D, C_RATE_I, C_RATE_P,
                      C_T_NOM, C_THR_MAX, C_THR_MIN, C_THR_XY_MARG, C_TILT_MAX, C_TILT_RATE_MAX,
                      C_VEL_D, C_VEL_DN_MAX, C_VEL_I, C_VEL_P, C_VEL_UP_MAX, C_VEL_XY_MAX,
                      C_YAW_MOM_MAX, C_YAW_P, C_YAW_RATE_MAX, C_ZPOS_P, C_ZVEL_I, C_ZVEL_P, S_CNT,
                      S_HOVER, S_N, S_WCMD, S_YAWHOLD, control_step, empty_setpoint)
from .physics import E_N, E_TR, E_WIND, X_N, X_R, initial_state, plant_params, rk4_step


@njit
def advance(x, s, prm, cp, sp, env, n, dt, decim, scratch, fifo, head):
    """Advance `n` physics steps of `dt`; returns how many of them ended resting on the ground.
    `fifo` (N, 4) holds the last N commands, `head[0]` the index of the oldest (N = 0: no delay)."""
    k1 = scratch[0]
    k2 = scratch[1]
    k3 = scratch[2]
    k4 = scratch[3]
    tmp = scratch[4]
    f4 = scratch[5]
    wcmd = np.empty(4)
    resting = 0
    for _ in range(n):
        if s[S_CNT] <= 0.0:
            control_step(x, prm, cp, sp, s)
            s[S_CNT] = decim
        s[S_CNT] -= 1.0
        nd = fifo.shape[0]
        if nd == 0:
            for i in range(4):
                wcmd[i] = s[S_WCMD + i]
        else:  # the oldest command goes to the motors, the newest takes its place
            h = head[0]
            for i in range(4):
                wcmd[i] = fifo[h, i]
                fifo[h, i] = s[S_WCMD + i]
            head[0] = (h + 1) % nd
        if rk4_step(x, wcmd, prm, env, dt, k1, k2, k3, k4, tmp, f4):
            resting += 1
    return resting


class VehicleModel:
    """One quadrotor (plant + cascade) as arrays; `step(n)` runs the compiled loop.

    `physics_hz` ≥ 500 (default 1000); the controller runs at `vehicle.controller.rate_hz`
    rounded to an integer divisor of the physics rate.
    """

    def __init__(self, vehicle, physics_hz: float = 1000.0, yaw: float = 0.0, pos=(0.0, 0.0, 0.0),
                 actuator_delay_s: float = 0.0):
        vehicle.require(SITL_KEYS, "the SITL")  # its rotor model and inertia (optional in a vehicle file)
        if physics_hz < 500.0:
            raise ValueError("physics_hz must be at least 500")
        if not (math.isfinite(actuator_delay_s) and 0.0 <= actuator_delay_s <= 1.0):
            raise ValueError("actuator_delay_s must be in [0, 1] s")
        self.vehicle = vehicle
        self.dt = 1.0 / physics_hz
        self.decim = max(1, round(physics_hz / vehicle.controller.rate_hz))
        self.x = initial_state(yaw, pos)
        self.prm = plant_params(vehicle, G)
        self.cp = controller_params(vehicle, self.decim * self.dt)
        self.sp = empty_setpoint()
        self.s = np.zeros(S_N)
        self.s[S_HOVER] = vehicle.controller.thr_hover
        self.s[S_YAWHOLD] = yaw
        self.env = np.zeros(E_N)
        self.env[E_TR] = 1.0
        self._scratch = np.zeros((6, X_N))
        # the command FIFO: N = round(delay / dt) physics steps, filled with "rotors stopped" (the vehicle
        # starts at rest with its rotors stopped; `Sim._start_airborne` fills it with the hover command)
        self.delay_steps = round(actuator_delay_s / self.dt)
        self.fifo = np.zeros((self.delay_steps, 4))
        self._head = np.zeros(1, np.int64)
        self.resting = True
        self.step(0)  # compile / load the cached kernel now, not in the first real-time tick

    # ----- inputs
    @property
    def thrust_ratio(self) -> float:
        return float(self.env[E_TR])

    @thrust_ratio.setter
    def thrust_ratio(self, value: float) -> None:
        self.env[E_TR] = float(value)

    def set_wind(self, w) -> None:
        self.env[E_WIND : E_WIND + 3] = w

    def step(self, n: int) -> None:
        rest = advance(self.x, self.s, self.prm, self.cp, self.sp, self.env, int(n), self.dt,
                       float(self.decim), self._scratch, self.fifo, self._head)
        if n > 0:
            self.resting = rest > 0 and self.x[2] >= 0.0

    # ----- outputs
    @property
    def pos(self) -> np.ndarray:
        return self.x[0:3]

    @property
    def vel(self) -> np.ndarray:
        return self.x[3:6]

    @property
    def quat(self) -> np.ndarray:
        return self.x[6:10]

    @property
    def rates(self) -> np.ndarray:
        return self.x[10:13]

    @property
    def rotor_speeds(self) -> np.ndarray:
        return self.x[X_R : X_R + 4]

    @property
    def hover_thrust(self) -> float:
        return float(self.s[S_HOVER])


def controller_params(vehicle, dt: float) -> np.ndarray:
    """Pack the vehicle's controller gains and limits (SI) into the controller parameter array.

    Autopilot limits changeable through parameters (tilt, velocity limits) are overwritten by the
    autopilot emulation (`Autopilot.apply_limits`).
    """
    c = vehicle.controller
    cp = np.zeros(C_N)
    cp[C_POS_P] = c.pos_p
    cp[C_ZPOS_P] = c.z_pos_p
    cp[C_VEL_P] = c.vel_p
    cp[C_VEL_I] = c.vel_i
    cp[C_VEL_D] = c.vel_d
    cp[C_ZVEL_P] = c.z_vel_p
    cp[C_ZVEL_I] = c.z_vel_i
    cp[C_ATT_P] = c.att_p
    cp[C_YAW_P] = c.yaw_p
    cp[C_RATE_P] = c.rate_p
    cp[C_RATE_I] = c.rate_i
    cp[C_RATE_D] = c.rate_d
    cp[C_THR_MAX] = vehicle.collective_max_fraction  # usable collective (PX4 MPC_THR_MAX)
    cp[C_THR_MIN] = 0.12  # PX4 MPC_THR_MIN default
    cp[C_THR_XY_MARG] = c.thr_xy_margin
    cp[C_TILT_MAX] = vehicle.tilt_max
    cp[C_TILT_RATE_MAX] = vehicle.tilt_rate_max
    cp[C_YAW_RATE_MAX] = math.radians(vehicle.yaw_rate_max_deg_s)
    cp[C_VEL_XY_MAX] = 12.0  # PX4 MPC_XY_VEL_MAX default
    cp[C_VEL_UP_MAX] = 3.0  # PX4 MPC_Z_VEL_MAX_UP default
    cp[C_VEL_DN_MAX] = 1.5  # PX4 MPC_Z_VEL_MAX_DN default
    cp[C_HTE_TAU] = 2.0  # hover-thrust estimate time constant [s]
    cp[C_T_NOM] = vehicle.t_nom_n
    cp[C_YAW_MOM_MAX] = vehicle.yaw_moment_max_nm
    cp[C_DT] = dt
    cp[C_IDLE] = 0.03  # armed idle: 3 % of maximum thrust
    return cp
