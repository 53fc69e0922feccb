"""The C ports driven from Python through ctypes: the same inputs into the C step and the Python
step, for the bit-for-bit tests and the benchmark. `build_port_library` compiles them.

The numpy dtypes below mirror the C structs of `cf_engagement.h` and `cf_steering.h` (8-byte
fields only, so no padding); parameters go in as flat arrays of doubles in dataclass order.
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from carfeel.export.variables import flat_values
from carfeel.models.gearshift.engagement import (
    EngagementInputs,
    EngagementParams,
    EngagementState,
    Stage,
)
from carfeel.models.steering.physical import (
    PhysicalInputs,
    PhysicalOutputs,
    PhysicalParams,
    PhysicalState,
)
from carfeel.models.steering.torque import SteeringTorqueParams
from carfeel.models.vehicle.single_track import VehicleParams, VehicleState

STAGES = list(Stage)
"""Stage by the C enum's number."""

ENGAGEMENT_STATE = np.dtype(
    [
        ("stage", "<i8"),
        ("position_m", "<f8"),
        ("velocity_m_s", "<f8"),
        ("stage_time_s", "<f8"),
        ("synchronization_progress", "<f8"),
        ("tooth_force_N", "<f8"),
        ("rng_state", "<u8"),
        ("index_end_m", "<f8"),
        ("reversal_s", "<f8"),
        ("contact_m", "<f8"),
    ]
)
ENGAGEMENT_INPUTS = np.dtype(
    [
        ("driver_force_N", "<f8"),
        ("wall_stiffness_N_m", "<f8"),
        ("wall_damping_N_s_m", "<f8"),
        ("wall_position_m", "<f8"),
        ("gate_open", "<i8"),
        ("extra_friction_N", "<f8"),
        ("gear_inertia_kg_m2", "<f8"),
        ("gear_drag_Nm", "<f8"),
    ]
)
ENGAGEMENT_OUTPUTS = np.dtype(
    [
        ("position_m", "<f8"),
        ("velocity_m_s", "<f8"),
        ("force_N", "<f8"),
        ("reaction_N", "<f8"),
        ("stage", "<i8"),
    ]
)
VEHICLE_STATE = np.dtype([(name, "<f8") for name in VehicleState._fields])
PHYSICAL_STATE = np.dtype([(name, "<f8") for name in PhysicalState._fields])
PHYSICAL_INPUTS = np.dtype([(name, "<f8") for name in PhysicalInputs._fields])
PHYSICAL_OUTPUTS = np.dtype([(name, "<f8") for name in PhysicalOutputs._fields])


def _pointer(array: np.ndarray) -> ctypes.c_void_p:
    return ctypes.c_void_p(array.ctypes.data)


def _doubles(values: Sequence[float]) -> np.ndarray:
    return np.ascontiguousarray(values, dtype="<f8")


def engagement_inputs(inputs: Sequence[EngagementInputs]) -> np.ndarray:
    """Python inputs as the C struct array (None: gate_open -1, the gear's load NaN)."""
    out = np.zeros(len(inputs), ENGAGEMENT_INPUTS)
    for k, u in enumerate(inputs):
        out[k] = (
            u.driver_force_N, u.wall_stiffness_N_m, u.wall_damping_N_s_m, u.wall_position_m,
            -1 if u.gate_open is None else int(u.gate_open), u.extra_friction_N,
            np.nan if u.gear_inertia_kg_m2 is None else u.gear_inertia_kg_m2,
            np.nan if u.gear_drag_Nm is None else u.gear_drag_Nm,
        )  # fmt: skip
    return out


def engagement_state(state: EngagementState) -> np.ndarray:
    out = np.zeros(1, ENGAGEMENT_STATE)
    out[0] = (
        STAGES.index(state.stage), state.position_m, state.velocity_m_s, state.stage_time_s,
        state.synchronization_progress, state.tooth_force_N, state.rng_state, state.index_end_m,
        state.reversal_s, state.contact_m,
    )  # fmt: skip
    return out


def python_state(record: Any) -> EngagementState:
    """A C state record as the Python model's state."""
    return EngagementState(
        STAGES[int(record["stage"])], float(record["position_m"]), float(record["velocity_m_s"]),
        float(record["stage_time_s"]), float(record["synchronization_progress"]),
        float(record["tooth_force_N"]), int(record["rng_state"]), float(record["index_end_m"]),
        float(record["reversal_s"]), float(record["contact_m"]),
    )  # fmt: skip


class Port:
    """The compiled ports (`carfeel.export.build.build_port_library`)."""

    def __init__(self, library: Path) -> None:
        self.library = ctypes.CDLL(str(library))
        void, size = ctypes.c_void_p, ctypes.c_size_t
        double = ctypes.c_double
        lib = self.library
        lib.cf_engagement_run.argtypes = [void, void, size, void, double, void, void]
        lib.cf_engagement_run.restype = None
        lib.cf_torque_run.argtypes = [void, void, void, size, void, void]
        lib.cf_torque_run.restype = None
        lib.cf_vehicle_run.argtypes = [void, void, void, size, void, double, void, void]
        lib.cf_vehicle_run.restype = None
        lib.cf_physical_run.argtypes = [void, void, size, void, double, void, void]
        lib.cf_physical_run.restype = None
        lib.cf_steady_state_run.argtypes = [void, void, size, void, void]
        lib.cf_steady_state_run.restype = None
        lib.cf_port_next_uniform.argtypes = [ctypes.c_uint64, ctypes.POINTER(double)]
        lib.cf_port_next_uniform.restype = ctypes.c_uint64

    def next_uniform(self, state: int) -> tuple[int, float]:
        u = ctypes.c_double()
        new = self.library.cf_port_next_uniform(ctypes.c_uint64(state), ctypes.byref(u))
        return int(new), u.value

    def engagement_run(
        self,
        params: EngagementParams,
        state: EngagementState,
        inputs: np.ndarray,
        dt_s: float,
        record: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Step the C engagement over `inputs` (ENGAGEMENT_INPUTS); (states, outputs) after
        each step (empty unless `record`; the last state is always returned first)."""
        flat = _doubles(flat_values(params))
        start = engagement_state(state)
        n = len(inputs)
        states = np.zeros(n if record else 0, ENGAGEMENT_STATE)
        outputs = np.zeros(n if record else 0, ENGAGEMENT_OUTPUTS)
        self.library.cf_engagement_run(
            _pointer(start), _pointer(inputs), n, _pointer(flat), dt_s,
            _pointer(states) if record else None, _pointer(outputs) if record else None,
        )  # fmt: skip
        return (states if record else start), outputs

    def torque_run(
        self,
        params: SteeringTorqueParams,
        speed_m_s: Sequence[float],
        rate_rad_s: Sequence[float],
        ay_m_s2: Sequence[float],
    ) -> np.ndarray:
        """(n, 5) terms of the C law: tau, tau0..tau3."""
        speed, rate, ay = _doubles(speed_m_s), _doubles(rate_rad_s), _doubles(ay_m_s2)
        terms = np.zeros((len(speed), 5), "<f8")
        flat = _doubles(flat_values(params))
        self.library.cf_torque_run(
            _pointer(speed), _pointer(rate), _pointer(ay), len(speed), _pointer(flat),
            _pointer(terms),
        )  # fmt: skip
        return terms

    def vehicle_run(
        self,
        params: VehicleParams,
        state: VehicleState,
        speed_m_s: Sequence[float],
        angle_rad: Sequence[float],
        dt_s: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(states after each step, the front axle's Ay after each step) of the C car."""
        speed, angle = _doubles(speed_m_s), _doubles(angle_rad)
        start = np.array([tuple(state)], VEHICLE_STATE)
        states = np.zeros(len(speed), VEHICLE_STATE)
        aligning = np.zeros(len(speed), "<f8")
        flat = _doubles(flat_values(params))
        self.library.cf_vehicle_run(
            _pointer(start), _pointer(speed), _pointer(angle), len(speed), _pointer(flat), dt_s,
            _pointer(states), _pointer(aligning),
        )  # fmt: skip
        return states, aligning

    def steady_state_run(
        self, params: VehicleParams, speed_m_s: Sequence[float], angle_rad: Sequence[float]
    ) -> np.ndarray:
        speed, angle = _doubles(speed_m_s), _doubles(angle_rad)
        ay = np.zeros(len(speed), "<f8")
        flat = _doubles(flat_values(params))
        self.library.cf_steady_state_run(
            _pointer(speed), _pointer(angle), len(speed), _pointer(flat), _pointer(ay)
        )
        return ay

    def physical_run(
        self,
        params: PhysicalParams,
        state: PhysicalState,
        inputs: Sequence[PhysicalInputs] | np.ndarray,
        dt_s: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(states, outputs) after each step of the C physical steering model; `inputs` as
        PhysicalInputs or as a PHYSICAL_INPUTS array."""
        flat = _doubles(flat_values(params))
        start = np.array([tuple(state)], PHYSICAL_STATE)
        records = (
            inputs
            if isinstance(inputs, np.ndarray)
            else np.array([tuple(u) for u in inputs], PHYSICAL_INPUTS)
        )
        states = np.zeros(len(records), PHYSICAL_STATE)
        outputs = np.zeros(len(records), PHYSICAL_OUTPUTS)
        self.library.cf_physical_run(
            _pointer(start), _pointer(records), len(records), _pointer(flat), dt_s,
            _pointer(states), _pointer(outputs),
        )  # fmt: skip
        return states, outputs
