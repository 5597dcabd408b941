"""The truth's RK4 step compiled for this host (sim_hil/csrc/truth.c), the simulator's fast path.

truth.c is a line-for-line twin of ``dynamics.derivative`` and ``rk4_step`` (the balloon, the lumped
rope ``rope.rope_derivative`` and the paper's rope, every truth option), built like the C core
(``firmware_c.build.shared_library``: a library named by the hash of its source and flags, at install
and else at first use) and called through ctypes with the state in a numpy array. The Python functions
stay the reference (``Simulation(..., reference=True)``) and the fallback when there is no C compiler;
tests/unit/test_truth_native.py holds the two together on the same states.

    python -m sim_hil.native        # build it, print its path
"""

from __future__ import annotations

import ctypes as C
import os
import sys
from pathlib import Path

import numpy as np

from balloon_core.atmosphere import G0, ISA_EXP, LAPSE_K_M, R_AIR
from sim_hil.dynamics import BalloonPhysics
from sim_hil.rope import AIRBORNE_BELOW_M, GROUND_FRICTION_RATIO, GROUND_STIFFNESS_N_M

HERE = Path(__file__).resolve().parent
SOURCES = [HERE / "csrc" / "truth.c"]
# no fused multiply-add: each operation rounds as Python's does
FLAGS = ("-std=c99", "-O2", "-fPIC", "-shared", "-Wall", "-Wextra", "-Werror", "-Wshadow", "-ffp-contract=off",
         "-fno-builtin-pow")  # pow(x, 2.0) stays libm's pow, as Python's x ** 2 is, not x * x
DISABLE_ENV = "BALLOON_SIM_REFERENCE"  # set (to anything but "" or "0"): the Python reference path everywhere

# truth.c's sim_params, in its order
CONSTANT_FIELDS = ("g0", "r_air", "lapse_k_m", "isa_exp", "ground_stiffness_n_m", "ground_friction_ratio")
PHYSICS_FIELDS = (
    "radius_m", "volume_m3", "mass_kg", "inertia_kgm2", "drag_factor", "added_mass_coefficient", "tether_length_m",
    "rope_kg_m", "tether_k_n_m", "tether_c_ns_m", "rope_drag_factor", "rot_damping_nms", "fluid_acceleration",
    "ground_pressure_pa", "ground_temperature_k", "isa_density", "reynolds_drag", "frontal_area_m2",
    "air_viscosity_pas", "drag_crisis_reynolds", "drag_crisis_exponent", "static_moment_kgm", "inertia_z_kgm2",
    "shear_exponent", "shear_reference_m", "veer_rad_m", "yaw_moment_m3",
)  # fmt: skip
ROPE_FIELDS = (  # (C name, LumpedRope attribute)
    ("segments", "segments"), ("seg_length_m", "seg_length_m"), ("node_mass_kg", "node_mass_kg"),
    ("seg_k_n_m", "seg_k_n_m"), ("seg_c_ns_m", "seg_c_ns_m"), ("rope_drag_factor_m2", "drag_factor_m2"),
    ("rope_shear_exponent", "shear_exponent"), ("rope_shear_reference_m", "shear_reference_m"),
    ("ground_c_ns_m", "ground_c_ns_m"), ("seg_rate_mps", "seg_rate_mps"), ("rope_veer_rad_m", "veer_rad_m"),
)  # fmt: skip


class SimParams(C.Structure):
    _fields_ = [
        (n, C.c_double)
        for n in (*CONSTANT_FIELDS, *PHYSICS_FIELDS, "has_rope", *(c for c, _ in ROPE_FIELDS), "airborne_below_m")
    ]


_LIB: C.CDLL | None = None
_WHY_NOT = ""


def _load() -> C.CDLL | None:
    global _LIB, _WHY_NOT
    if _LIB is not None or _WHY_NOT:
        return _LIB
    try:
        from firmware_c.build import BuildError, shared_library  # host build helper, shared with the C core

        path = shared_library("libbwtruth", SOURCES, [], FLAGS, "the simulator's C physics")
        lib = C.CDLL(str(path))
    except (BuildError, OSError) as e:
        _WHY_NOT = str(e)
        return None
    lib.bw_sim_params_size.restype = C.c_size_t
    if lib.bw_sim_params_size() != C.sizeof(SimParams):
        _WHY_NOT = "truth.c's sim_params does not match native.SimParams"
        return None
    dp = C.POINTER(C.c_double)
    lib.bw_sim_derivative.argtypes = [C.POINTER(SimParams), dp, dp, dp]
    lib.bw_sim_derivative.restype = C.c_double
    lib.bw_sim_step.argtypes = [C.POINTER(SimParams), dp, C.c_int, C.c_double, dp, C.c_int, dp, dp]
    lib.bw_sim_step.restype = C.c_double
    lib.bw_sim_steps.argtypes = [C.POINTER(SimParams), dp, C.c_int, C.c_double, dp, C.c_int, C.c_int, dp, dp]
    lib.bw_sim_steps.restype = C.c_double
    _LIB = lib
    return lib


def available() -> bool:
    """The compiled physics can be used (built or buildable, and not turned off by ``DISABLE_ENV``)."""
    if os.environ.get(DISABLE_ENV, "") not in ("", "0"):
        return False
    return _load() is not None


def why_not() -> str:
    """Why ``available()`` is False (empty when it is not)."""
    if os.environ.get(DISABLE_ENV, "") not in ("", "0"):
        return f"{DISABLE_ENV} is set"
    _load()
    return _WHY_NOT


def params(ph: BalloonPhysics) -> SimParams:
    """The C struct of one ``BalloonPhysics`` (rebuilt whenever the physics change: a winch)."""
    p = SimParams(G0, R_AIR, LAPSE_K_M, ISA_EXP, GROUND_STIFFNESS_N_M, GROUND_FRICTION_RATIO)
    for name in PHYSICS_FIELDS:
        setattr(p, name, float(getattr(ph, name)))
    if ph.rope is not None:
        p.has_rope = 1.0
        for cname, attr in ROPE_FIELDS:
            setattr(p, cname, float(getattr(ph.rope, attr)))
        p.airborne_below_m = AIRBORNE_BELOW_M
    return p


class NativeStepper:
    """RK4 steps of one flight in C: the state lives in ``self.s`` (numpy float64, the layout of
    ``dynamics.resting_state``), the derivative at the step's start in ``self.k1``; ``step_keep`` also
    keeps the state before the step in ``self.pre`` with the rope's anchor tension and airborne flag
    after it (``rope.anchor_tension_n``, ``rope.rope_airborne``)."""

    def __init__(self, ph: BalloonPhysics, state: list[float]) -> None:
        lib = _load()
        if lib is None:
            raise RuntimeError(f"the simulator's C physics are not available: {_WHY_NOT}")
        self._step = lib.bw_sim_step
        self._steps = lib.bw_sim_steps
        self._deriv = lib.bw_sim_derivative
        self.s = np.array(state, dtype=np.float64)
        self.k1 = np.zeros_like(self.s)
        self.pre = np.zeros(len(self.s) + 2)
        dp = C.POINTER(C.c_double)
        self._pre_p = self.pre.ctypes.data_as(dp)
        self._s_p = self.s.ctypes.data_as(dp)
        self._k1_p = self.k1.ctypes.data_as(dp)
        self._n = C.c_int(len(self.s))
        self.set_physics(ph)
        self._wind = np.zeros((1, 6))
        self._wind_p = self._wind.ctypes.data_as(dp)

    def set_physics(self, ph: BalloonPhysics) -> None:
        self._params = params(ph)
        self._params_p = C.pointer(self._params)

    def set_wind(self, rows: np.ndarray) -> None:
        """The wind (n, e, d, dn, de, dd) at half steps, rows 2j, 2j + 1, 2j + 2 for step j of ``step``."""
        self._wind = np.ascontiguousarray(rows, dtype=np.float64)
        self._wind_p = self._wind.ctypes.data_as(C.POINTER(C.c_double))

    def step(self, h: float, j: int) -> float:
        """k1 at the state, then one RK4 step of ``h`` with the wind rows of step ``j``; the tension at the
        state before the step."""
        return self._step(self._params_p, self._s_p, self._n, h, self._wind_p, j, self._k1_p, None)

    def step_keep(self, h: float, j: int) -> float:
        """``step``, the state before it (and the rope's anchor tension and airborne flag) kept in ``pre``."""
        return self._step(self._params_p, self._s_p, self._n, h, self._wind_p, j, self._k1_p, self._pre_p)

    def steps_keep(self, h: float, j: int, count: int) -> float:
        """``step_keep`` then ``count - 1`` more steps (j + 1, ...), in one call."""
        return self._steps(self._params_p, self._s_p, self._n, h, self._wind_p, j, count, self._k1_p, self._pre_p)

    def derivative(self, w: tuple[float, ...]) -> float:
        """k1 (into ``self.k1``) at the state without stepping: the tension."""
        wa = (C.c_double * 6)(*w)
        return self._deriv(self._params_p, self._s_p, wa, self._k1_p)


def main() -> int:
    if _load() is None:
        print(f"sim_hil.native: {_WHY_NOT}", file=sys.stderr)
        return 2
    from firmware_c.build import shared_library

    print(shared_library("libbwtruth", SOURCES, [], FLAGS, "the simulator's C physics"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
