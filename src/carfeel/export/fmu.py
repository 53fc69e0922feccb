"""FMU export: the steering torque law or the gear engagement as a self-contained C FMU.

An FMU (FMI 2.0 or 3.0, co-simulation) holds `modelDescription.xml`, the C sources under
`sources/` and a shared library built here from those very sources by the distribution's C
compiler (`binaries/linux64/` for FMI 2, `binaries/x86_64-linux/` for FMI 3). No Python runs in
it: any number of instances of any number of carfeel FMUs run in one process.

    carfeel/export/c/cf_engagement.c  port of models/gearshift/engagement.py (+ mechanics, rng)
    carfeel/export/c/cf_steering.c    port of models/steering/torque.py (+ vehicle/single_track)
    carfeel/export/c/cf_model_*.c     each FMU's model: inputs held over a step, parameter checks
    carfeel/export/c/cf_fmu.c         instances, modes, get/set by value reference, whole steps
    carfeel/export/c/cf_fmi2.c, cf_fmi3.c   the FMI functions over cf_fmu.c
    cf_generated.c (written here)     the variables' table and the preset's values

The FMI headers are the standard's (2-clause BSD), copied from the installed FMPy (the extra
`carfeel[fmu]`), as the standard requires them among an FMU's sources. Parameters, their units
and their ranges come from the preset and its schema (`carfeel.schema`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.util
import math
import os
import platform
import shutil
import subprocess
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from carfeel import __version__
from carfeel.errors import CarfeelError, InputError
from carfeel.io.force_profile import MAX_FORCE_N
from carfeel.io.presets import MAX_NAME_CHARS as PRESET_NAME_CHARS
from carfeel.io.presets import STEERING_STEP_S as PHYSICAL_MAX_STEP_S
from carfeel.io.presets import Preset
from carfeel.models.gearshift.engagement import (
    ChamferParams,
    DetentParams,
    EngagementParams,
    Stage,
)
from carfeel.models.mechanics import StageMechanics
from carfeel.models.steering.physical import SystemParams, TyreParams
from carfeel.models.steering.torque import SteeringTorqueParams
from carfeel.models.vehicle.single_track import VehicleParams
from carfeel.schema import Range, field_docs, range_of, unit_of
from carfeel.simulation.shift import MAX_STEP_S as SHIFT_MAX_STEP_S
from carfeel.simulation.shift import ShiftParams
from carfeel.simulation.steering import MAX_STEP_S as STEERING_MAX_STEP_S
from carfeel.simulation.steering import SteeringCar

MODELS = ("steering", "shift")
STEERING_MODELS = ("paper", "physical")
"""The steering FMU's model: the paper's law, or the physical model (`--steering-model`)."""
FMI_VERSIONS = (2, 3)
INTEGER_MAX = {2: 2**31 - 1, 3: 2**63 - 1}
"""The largest value of an FMI integer variable: FMI 2's Integer (32 bits), FMI 3's Int64."""


def signed_seed(seed: int) -> int:
    """carfeel's seed (0 .. 2^64-1) as the FMU's signed seed parameter (two's complement)."""
    return seed - 2**64 if seed >= 2**63 else seed


MODEL_STEP_S = 1e-3
"""The FMUs' default model step (the 1 kHz loop's); the parameter model_step_s changes it."""

CFLAGS = (
    "-std=c99",
    "-O2",
    "-ffp-contract=off",  # no fused multiply-add: Python rounds every operation
    "-fno-fast-math",
    "-fno-builtin",  # libm's pow(x, 2.0) as Python calls it, not x * x; no sin+cos -> sincos
    "-fPIC",
    "-fvisibility=hidden",  # only the fmi2*/fmi3* functions are exported
    "-Wall",
    "-Wextra",
)
"""How the FMU's library is compiled; the same flags give the port's bit-for-bit equality."""

AY_SOURCES = ("input", "vehicle", "front_axle", "steady_state")
"""Where the steering FMU's tau0 takes Ay from (its parameter ay_source), in the C enum's order."""

PORT_SOURCES = ("cf_engagement.c", "cf_steering.c", "cf_physical.c", "cf_port_runs.c")
COMMON_SOURCES = ("cf_fmu.c",)
HEADERS = {
    2: ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"),
    3: ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h"),
}
PLATFORM_FOLDER = {2: "linux64", 3: "x86_64-linux"}


class ExportError(CarfeelError):
    """An FMU cannot be built here: a missing compiler or extra, an unsupported platform."""


MAX_NAME_CHARS = PRESET_NAME_CHARS
"""The longest preset name an FMU carries (in its model name, its description and a C string:
a name is a label, and a longer one is refused before anything is written)."""


def _refused_character(char: str) -> bool:
    """What XML 1.0 cannot hold (C0 controls but tab, newline and return; U+FFFE, U+FFFF; lone
    surrogates), and DEL and the C1 controls, which XML holds but a terminal that prints the
    name may obey (0x9B starts an escape sequence)."""
    code = ord(char)
    if code < 0x20:
        return char not in "\t\n\r"
    return 0x7F <= code <= 0x9F or 0xD800 <= code <= 0xDFFF or code in (0xFFFE, 0xFFFF)


def checked_name(name: str) -> str:
    """A preset's name as an FMU may carry it; InputError naming the character or the limit.

    The name is data wherever it goes: an attribute of modelDescription.xml (ElementTree
    escapes it), escaped HTML in the documentation, an escaped C string literal (`c_string`)."""
    if len(name) > MAX_NAME_CHARS:
        raise InputError(
            f"the preset's name is {len(name)} characters long; an FMU takes at most "
            f"{MAX_NAME_CHARS}: shorten `name` in the preset file"
        )
    bad = next((c for c in name if _refused_character(c)), None)
    if bad is not None:
        raise InputError(
            f"the preset's name holds the control character U+{ord(bad):04X} at position "
            f"{name.index(bad)}, which an FMU's modelDescription.xml cannot carry (or a terminal "
            "would obey): remove it from `name` in the preset file"
        )
    return name


@dataclass(frozen=True, slots=True)
class Variable:
    """One FMU variable: its name, role, the C member of struct cf_model it lives in."""

    name: str
    causality: str
    """parameter, input or output."""
    variability: str
    """fixed, tunable (parameters), continuous (reals) or discrete (integers)."""
    kind: str
    """real, integer or an enumeration type's name (stored as an integer)."""
    c_member: str
    description: str
    start: float | int | None = None
    unit: str = ""
    low: float = -math.inf
    high: float = math.inf
    low_inclusive: bool = True
    high_inclusive: bool = True
    fmi3_integer: str = "Int64"
    """The FMI 3 type of an integer variable (Int32 or Int64); enumerations are Int64."""

    @property
    def is_real(self) -> bool:
        return self.kind == "real"


@dataclass(frozen=True, slots=True)
class ModelSpec:
    """Everything an export of one model with one preset needs."""

    model: str
    identifier: str
    title: str
    description: str
    preset: str
    source_file: str
    """The model's C file (its header has the same stem)."""
    ports: tuple[str, ...]
    """The C ports it steps (file stems: a .c and a .h each)."""
    variables: tuple[Variable, ...]
    defaults: tuple[tuple[str, float | int], ...]
    """Every member of struct cf_model the preset gives a value (parameters used or not)."""
    enumerations: tuple[tuple[str, tuple[tuple[str, str], ...]], ...]
    """(type name, ((item, description), ...)): item values 0, 1, ..."""


# -- variables ---------------------------------------------------------------------------------


_FMI_UNITS: dict[str, tuple[str, dict[str, int]]] = {
    "N": ("N", {"kg": 1, "m": 1, "s": -2}),
    "m": ("m", {"m": 1}),
    "s": ("s", {"s": 1}),
    "kg": ("kg", {"kg": 1}),
    "rad": ("rad", {"rad": 1}),
    "m/s": ("m/s", {"m": 1, "s": -1}),
    "m/s^2": ("m/s2", {"m": 1, "s": -2}),
    "N/m": ("N/m", {"kg": 1, "s": -2}),
    "N*s/m": ("N.s/m", {"kg": 1, "s": -1}),
    "Nm": ("N.m", {"kg": 1, "m": 2, "s": -2}),
    "kg*m^2": ("kg.m2", {"kg": 1, "m": 2}),
    "N/rad": ("N/rad", {"kg": 1, "m": 1, "s": -2, "rad": -1}),
    "rad/s": ("rad/s", {"rad": 1, "s": -1}),
    "Nm/rad": ("N.m/rad", {"kg": 1, "m": 2, "s": -2, "rad": -1}),
    "Nm*s/rad": ("N.m.s/rad", {"kg": 1, "m": 2, "s": -1, "rad": -1}),
    "Nm*s/rad per (m/s)^2": ("N.m.s3/(rad.m2)", {"kg": 1, "s": 1, "rad": -1}),
    "Nm/(m/s^2)": ("N.m.s2/m", {"kg": 1, "m": 1}),
    "1/Nm": ("1/(N.m)", {"kg": -1, "m": -2, "s": 2}),
    "s/(m*Nm)": ("s/(m.N.m)", {"kg": -1, "m": -3, "s": 3}),
    "Hz": ("Hz", {"s": -1}),
}
"""carfeel's unit -> the FMU's unit (Modelica's SI spelling, as Modelica tools parse it) and its
base units."""


def fmi_unit(unit: str) -> str:
    return _FMI_UNITS[unit][0] if unit else ""


def _flatten(value: Any, prefix: str = "") -> Iterator[tuple[str, Any, type, str]]:
    """(dotted path, value, owning dataclass, field name) of every leaf field, in field order."""
    for field in dataclasses.fields(value):
        item = getattr(value, field.name)
        path = f"{prefix}{field.name}"
        if dataclasses.is_dataclass(item):
            yield from _flatten(item, f"{path}.")
        else:
            yield path, item, type(value), field.name


def flat_values(params: Any) -> list[float]:
    """A parameter dataclass as the flat list of doubles its C struct is (tests, benchmarks)."""
    return [float(value) for _, value, _, _ in _flatten(params)]


_STAGE_DOCS = {
    Stage.NEUTRAL: "free motion; the neutral spring and detent centre the lever",
    Stage.SYNCHRONIZATION: "the blocker ring holds the lever while the cones synchronize",
    Stage.GATE_OPEN: "free motion from the ring to the teeth",
    Stage.ENGAGEMENT: "the sleeve's chamfers meet the gear's teeth (and may turn the gear)",
    Stage.FREE_TRAVEL: "free motion to the end stop",
    Stage.STOP: "the elastic end stop around the in-gear position",
    Stage.IN_GEAR: "settled in gear, held by the stop's spring and the gear detent",
    Stage.RETURNING: "free motion back from past the ring",
}


def _parameter(table: str, path: str, value: float, doc: str, c_member: str) -> Variable:
    name = f"{table}.{path}"
    leaf = path.split(".")[-1]
    unit = unit_of(leaf)
    low, high, low_in, high_in = range_of(name) or Range(-math.inf, math.inf)
    text = doc or f"{leaf.replace('_', ' ')}"
    # The preset's name is in the model's description, once: not in every variable's.
    described = f"{text} [{unit or '-'}; the preset's [{table}] {path}]"
    return Variable(
        name, "parameter", "tunable", "real", c_member, described, float(value), unit,
        low, high, low_in, high_in,
    )  # fmt: skip


def _table_parameters(
    table: str,
    params: Any,
    used: Sequence[str] | None = None,
    c_struct: str | None = None,
) -> Iterator[Variable]:
    """The FMU parameters of one preset table (`used`: only those fields), named table.field;
    `c_struct` is the member of struct cf_model holding it (default: the table's name)."""
    docs: dict[type, dict[str, str]] = {}
    for path, value, owner, field in _flatten(params):
        if used is not None and path not in used:
            continue
        if owner not in docs:
            docs[owner] = field_docs(owner)
        member = f"{c_struct or table}.{path}"
        doc = docs[owner].get(field, "")
        yield _parameter(table, path, value, doc, member)


def _model_step(max_step_s: float, why: str) -> Variable:
    return Variable(
        "model_step_s", "parameter", "fixed", "real", "model_step_s",
        "The model's own step, s: each communication step is a whole number of model steps "
        f"with the inputs held over it (any other communication step is refused); {why}",
        MODEL_STEP_S, "s", 0.0, max_step_s, False, True,
    )  # fmt: skip


def shift_spec(preset: Preset[ShiftParams], seed: int = 0) -> ModelSpec:
    """The shift FMU: the 1-DOF engagement of `preset`'s gearbox, driven by a knob force."""
    gearbox = preset.params.gearbox
    name = checked_name(preset.name)
    real = "real"
    variables = [
        Variable("driver_force_N", "input", "continuous", real, "inputs.driver_force_N",
                 "Force the driver applies to the knob along the engagement slot, N, positive "
                 "toward the gear (carfeel's force_N)", 0.0, "N", -MAX_FORCE_N, MAX_FORCE_N),
        Variable("gate_open", "input", "discrete", "integer", "inputs.gate_open",
                 "-1: the model's own synchronizer opens the gate after "
                 "gearbox.synchronization_duration_s of pushing (the paper's, the default); "
                 "0 / 1: an outside synchronizer model says the speeds are not / are matched",
                 -1, "", -1, 1, fmi3_integer="Int32"),
        Variable("extra_friction_N", "input", "continuous", real, "inputs.extra_friction_N",
                 "Friction added to the stage's own, static and sliding, N (a latch)", 0.0, "N",
                 0.0, 1e3),
        Variable("wall_stiffness_N_m", "input", "continuous", real, "inputs.wall_stiffness_N_m",
                 "An outside spring on the lever (a gate wall), N/m; 0: none", 0.0, "N/m",
                 0.0, 1e7),
        Variable("wall_damping_N_s_m", "input", "continuous", real, "inputs.wall_damping_N_s_m",
                 "The outside spring's damping, N*s/m", 0.0, "N*s/m", 0.0, 1e5),
        Variable("wall_position_m", "input", "continuous", real, "inputs.wall_position_m",
                 "Where the outside spring is relaxed, m", 0.0, "m"),
        *_table_parameters("gearbox", gearbox),
        Variable("seed", "parameter", "fixed", "integer", "seed",
                 "Seed of the tooth draws (SplitMix64): the relative tooth angle of each "
                 "engagement; one seed gives one result, as carfeel's --seed N for N >= 0, "
                 "and N + 2^64 for N < 0 (FMI 2's 32-bit Integer reaches the seeds below 2^31 "
                 "and from 2^64 - 2^31; FMI 3's Int64 all)", signed_seed(seed),
                 fmi3_integer="Int64"),
        _model_step(SHIFT_MAX_STEP_S, "at most carfeel's shift step, where a hand closing the "
                    "loop through the importer stays accurate"),
        Variable("position_m", "output", "continuous", real, "outputs.position_m",
                 "Knob position along the engagement slot, m, 0 = neutral, positive toward the "
                 "gear (carfeel's position_m)", unit="m"),
        Variable("velocity_m_s", "output", "continuous", real, "outputs.velocity_m_s",
                 "Knob velocity, m/s (carfeel's velocity_m_s)", unit="m/s"),
        Variable("force_N", "output", "continuous", real, "outputs.force_N",
                 "The driver's force on the knob the step took, N (carfeel's force_N)",
                 unit="N"),
        Variable("reaction_N", "output", "continuous", real, "outputs.reaction_N",
                 "Force of the gearbox on the knob against the driver, N: the driver's force "
                 "less what accelerates the lever (F - m*a); what a force-feedback device "
                 "renders (carfeel's reaction_N)", unit="N"),
        Variable("stage", "output", "discrete", "Stage", "outputs.stage",
                 "Stage of the engagement (carfeel's stage column)"),
        Variable("synchronization_progress", "output", "continuous", real,
                 "synchronization_progress",
                 "Share of the synchronization done by the fixed synchronizer, 0..1; the gate "
                 "opens at 1"),
    ]  # fmt: skip
    defaults = [(f"gearbox.{path}", float(value)) for path, value, _, _ in _flatten(gearbox)]
    defaults += [("seed", signed_seed(seed)), ("model_step_s", MODEL_STEP_S)]
    stages = tuple((s.value, _STAGE_DOCS[s]) for s in Stage)
    return ModelSpec(
        "shift", "carfeel_shift", f"carfeel shift ({name})",
        "One gear engagement of a manual gearshift along its slot (1 DOF): the blocker ring's "
        "synchronization, the chamfers and dog teeth, the end stop, detents and stick-slip "
        "friction, driven by the driver's knob force (carfeel's models/gearshift/engagement.py, "
        "ported to C). Axis: 0 = neutral, positive toward the gear.",
        name, "cf_model_shift.c", ("cf_engagement",), tuple(variables), tuple(defaults),
        (("Stage", stages),),
    )  # fmt: skip


_VEHICLE_USED = (
    "mass_kg", "yaw_inertia_kg_m2", "wheelbase_m", "cg_to_front_axle_m",
    "front_cornering_stiffness_N_rad", "rear_cornering_stiffness_N_rad", "steering_ratio",
    "kinematic_speed_m_s",
)  # fmt: skip
"""The car's parameters the FMU's single-track car uses (not its width and lock)."""

_AY_DOCS = (
    "the input lateral_accel_m_s2: the importer's own vehicle model (as carfeel's telemetry)",
    "the FMU's linear single-track car from speed and angle (carfeel simulate steering)",
    "that car's front axle force as an Ay, F_f*L/(m*b): leads Ay in transients (the 1 kHz "
    "loop's --aligning front-axle)",
    "the steady-state Ay of the angle and speed (the paper's; --aligning steady-state)",
)


def steering_spec(preset: Preset[SteeringCar]) -> ModelSpec:
    """The steering FMU: the paper's torque law of `preset`'s car, Ay from the importer or the
    FMU's single-track car."""
    car = preset.params
    name = checked_name(preset.name)
    real = "real"
    variables = [
        Variable("speed_m_s", "input", "continuous", real, "speed_m_s",
                 "Vehicle speed Vx, m/s (carfeel's speed_m_s): the tire spin term falls with "
                 "|Vx|; the FMU's car needs it", 0.0, "m/s"),
        Variable("lateral_accel_m_s2", "input", "continuous", real, "lateral_accel_m_s2",
                 "Lateral acceleration Ay, m/s^2, positive to the left (carfeel's "
                 "lateral_accel_m_s2): tau0's input when ay_source = input; unused otherwise",
                 0.0, "m/s^2"),
        Variable("steering_angle_rad", "input", "continuous", real, "steering_angle_rad",
                 "Steering wheel angle, rad, positive to the left (carfeel's "
                 "steering_angle_rad): the FMU's car's input (ay_source vehicle, front_axle, "
                 "steady_state); unused with ay_source = input", 0.0, "rad"),
        Variable("steering_rate_rad_s", "input", "continuous", real, "steering_rate_rad_s",
                 "Steering wheel rate, rad/s, positive to the left (carfeel's "
                 "steering_rate_rad_s): the input of tau1, tau2 and tau3", 0.0, "rad/s"),
        *_table_parameters("torque", car.torque),
        *_table_parameters("vehicle", car.vehicle, _VEHICLE_USED),
        Variable("ay_source", "parameter", "fixed", "AySource", "ay_source",
                 "Where tau0 takes Ay from: " + "; ".join(
                     f"{name} = {i}: {doc}" for i, (name, doc) in
                     enumerate(zip(AY_SOURCES, _AY_DOCS, strict=True))), 0,
                 low=0, high=len(AY_SOURCES) - 1),
        _model_step(STEERING_MAX_STEP_S, "the car's trapezoidal step (with ay_source vehicle or "
                    "front_axle) and the friction's memory (torque.k10_Nm > 0)"),
        Variable("torque_Nm", "output", "continuous", real, "torque_Nm",
                 "Steering wheel torque tau = tau0 + tau1 + tau2 + tau3, Nm: the torque the "
                 "driver applies, positive counter-clockwise; each term resists the driver "
                 "(carfeel's torque_Nm)", unit="Nm"),
        Variable("torque_aligning_Nm", "output", "continuous", real, "torque_aligning_Nm",
                 "tau0 = K1*Ay/(1 + K2*|Ay|^K3), the aligning term, Nm", unit="Nm"),
        Variable("torque_tire_spin_Nm", "output", "continuous", real, "torque_tire_spin_Nm",
                 "tau1 = atan(rate/K6)/(K4 + K5*|Vx|), the tire spin term, Nm", unit="Nm"),
        Variable("torque_friction_Nm", "output", "continuous", real, "torque_friction_Nm",
                 "tau2 = K7*atan(rate/K8) + K10*z, the friction term and its memory z (a Dahl "
                 "element over K11 rad of steering; off with K10 = 0), Nm", unit="Nm"),
        Variable("torque_damping_Nm", "output", "continuous", real, "torque_damping_Nm",
                 "tau3 = K9*rate, the damping term, Nm", unit="Nm"),
        Variable("model_lateral_accel_m_s2", "output", "continuous", real,
                 "model_lateral_accel_m_s2", "The Ay tau0 took (see ay_source), m/s^2",
                 unit="m/s^2"),
        Variable("yaw_rate_rad_s", "output", "continuous", real, "yaw_rate_rad_s",
                 "The FMU's car's yaw rate, rad/s, positive to the left (0 unless ay_source is "
                 "vehicle or front_axle)", unit="rad/s"),
        Variable("sideslip_rad", "output", "continuous", real, "sideslip_rad",
                 "The FMU's car's sideslip, rad (0 unless ay_source is vehicle or front_axle)",
                 unit="rad"),
    ]  # fmt: skip
    defaults: list[tuple[str, float | int]] = [
        (f"torque.{path}", float(value)) for path, value, _, _ in _flatten(car.torque)
    ]
    defaults += [(f"vehicle.{path}", float(value)) for path, value, _, _ in _flatten(car.vehicle)]
    defaults += [("ay_source", 0), ("model_step_s", MODEL_STEP_S)]
    sources = tuple(zip(AY_SOURCES, _AY_DOCS, strict=True))
    return ModelSpec(
        "steering", "carfeel_steering", f"carfeel steering ({name})",
        "The steering wheel torque of the PERCRO 2005 paper's law, tau = tau0 + tau1 + tau2 + "
        "tau3 (aligning, tire spin, friction, damping; carfeel's models/steering/torque.py, "
        "ported to C), with Ay from the importer or from a linear single-track car. Signs: "
        "angle, rate, Ay and torque positive to the left (counter-clockwise).",
        name, "cf_model_steering.c", ("cf_steering",), tuple(variables), tuple(defaults),
        (("AySource", sources),),
    )  # fmt: skip


_PHYSICAL_OUTPUTS = (
    (
        "hand_angle_rad",
        "steering_angle_rad",
        "The rim's angle, rad, positive to the left (the input's when hands_on = 1)",
    ),
    ("hand_rate_rad_s", "steering_rate_rad_s", "The rim's rate, rad/s"),
    (
        "lateral_accel_m_s2",
        "lateral_accel_m_s2",
        "The car's lateral acceleration Ay, m/s^2, positive to the left",
    ),
    (
        "torque_Nm",
        "torque_Nm",
        "Torque the driver applies at the rim, Nm, positive "
        "counter-clockwise (each term resists the driver): the sum of the eight terms below",
    ),
    (
        "torque_aligning_Nm",
        "torque_aligning_Nm",
        "Aligning term: mechanical trail times the "
        "front axle's force plus the tyres' pneumatic moment, at the rim, Nm",
    ),
    (
        "torque_jacking_Nm",
        "torque_jacking_Nm",
        "Jacking term: the kingpin inclination lifting the car, Nm",
    ),
    ("torque_park_Nm", "torque_park_Nm", "Dry-park wind-up of the contact patches, Nm"),
    ("torque_friction_Nm", "torque_friction_Nm", "Column and rack friction (stick elements), Nm"),
    ("torque_damping_Nm", "torque_damping_Nm", "Rack and EPS damping, Nm"),
    ("torque_inertia_Nm", "torque_inertia_Nm", "Rim and rack inertia, Nm"),
    ("torque_stop_Nm", "torque_stop_Nm", "End stops at the car's lock, Nm"),
    (
        "torque_assist_Nm",
        "torque_assist_Nm",
        "EPS assist and active return, Nm (negative: it takes load off the driver)",
    ),
    (
        "torsion_bar_torque_Nm",
        "torsion_bar_torque_Nm",
        "Torque in the torsion bar and its compensation damper, Nm",
    ),
    ("front_wheel_angle_rad", "front_wheel_angle_rad", "Road wheel angle, rad"),
    (
        "front_grip_used",
        "front_grip_used",
        "Share of the front axle's grip used, 0..1 (above 0.95 it slides)",
    ),
    ("rear_grip_used", "rear_grip_used", "Share of the rear axle's grip used, 0..1"),
    ("yaw_rate_rad_s", "yaw_rate_rad_s", "The car's yaw rate, rad/s, positive to the left"),
    ("sideslip_rad", "sideslip_rad", "The car's sideslip, rad"),
    ("x_m", "x_m", "The car's position, m"),
    ("y_m", "y_m", "The car's position, m (left of the start heading)"),
    ("yaw_rad", "yaw_rad", "The car's heading, rad"),
)


def physical_steering_spec(preset: Preset[SteeringCar]) -> ModelSpec:
    """The steering FMU with the physical model (`models/steering/physical.py`) of `preset`'s
    car: its [vehicle], [tyres] and [steering_system] tables."""
    car = preset.params
    name = checked_name(preset.name)
    if car.tyres is None or car.steering_system is None:
        raise ExportError(
            f"preset {name} has no [tyres] and [steering_system] tables, which the "
            "physical steering model needs (the shipped b-segment and d-segment have them); "
            "export the paper's law instead (--steering-model paper)"
        )
    real = "real"
    used = tuple(p for p, _, _, _ in _flatten(car.vehicle) if p != "width_m")
    variables = [
        Variable("speed_m_s", "input", "continuous", real, "inputs.speed_m_s",
                 "Vehicle speed Vx, m/s (carfeel's speed_m_s)", 0.0, "m/s"),
        Variable("steering_angle_rad", "input", "continuous", real, "inputs.steering_angle_rad",
                 "The rim's angle, rad, positive to the left, imposed when hands_on = 1 (a "
                 "driver's or a device's); its value at initialization is the rim's start",
                 0.0, "rad"),
        Variable("steering_rate_rad_s", "input", "continuous", real,
                 "inputs.steering_rate_rad_s", "The rim's rate, rad/s, imposed with the angle",
                 0.0, "rad/s"),
        Variable("hand_torque_Nm", "input", "continuous", real, "inputs.hand_torque_Nm",
                 "The driver's torque on a free rim (hands_on = 0), Nm, positive "
                 "counter-clockwise; 0: hands off", 0.0, "Nm"),
        Variable("hands_on", "input", "continuous", real, "inputs.hands_on",
                 "1: the rim's angle and rate are imposed, the output is the torque into the "
                 "column; 0: the rim is free under hand_torque_Nm (a release); the threshold is "
                 "0.5", 1.0, "", 0.0, 1.0),
        *_table_parameters("vehicle", car.vehicle, used, "params.vehicle"),
        *_table_parameters("tyres", car.tyres, None, "params.tyres"),
        *_table_parameters(
            "steering_system", car.steering_system, None, "params.system"
        ),
        _model_step(PHYSICAL_MAX_STEP_S, "the preset's checks size the steering system for "
                    "1 ms (semi-implicit Euler)"),
        *(Variable(name, "output", "continuous", real, f"outputs.{member}", doc,
                   unit=unit_of(name)) for name, member, doc in _PHYSICAL_OUTPUTS),
    ]  # fmt: skip
    defaults: list[tuple[str, float | int]] = [
        (f"params.{table}.{path}", float(value))
        for table, params in (
            ("vehicle", car.vehicle), ("tyres", car.tyres), ("system", car.steering_system),
        )
        for path, value, _, _ in _flatten(params)
    ]  # fmt: skip
    defaults.append(("model_step_s", MODEL_STEP_S))
    return ModelSpec(
        "steering", "carfeel_steering_physical", f"carfeel physical steering ({name})",
        "The steering wheel torque of carfeel's physical model: brush tyres on a nonlinear "
        "single-track car (load transfer, relaxation length) and an EPS steering system (rim, "
        "torsion bar, rack, assist, friction, jacking, dry-park wind-up, end stops); "
        "carfeel's models/steering/physical.py, ported to C. Signs: angle, rate, Ay and "
        "torque positive to the left (counter-clockwise).",
        name, "cf_model_physical.c", ("cf_steering", "cf_physical"), tuple(variables),
        tuple(defaults), (),
    )  # fmt: skip


def spec_for(
    model: str, preset_name: str | None, seed: int = 0, steering_model: str = "paper"
) -> ModelSpec:
    """The spec of `model` with a preset (shipped name or path; the default preset if None)."""
    from carfeel.io.presets import DEFAULT_PRESETS, load_shift, load_steering

    if model == "shift":
        return shift_spec(load_shift(preset_name or DEFAULT_PRESETS["shift"]), seed)
    if model == "steering" and steering_model == "physical":
        return physical_steering_spec(load_steering(preset_name or DEFAULT_PRESETS["steering"]))
    if model == "steering" and steering_model == "paper":
        return steering_spec(load_steering(preset_name or DEFAULT_PRESETS["steering"]))
    if model == "steering":
        raise ExportError(f"steering model {steering_model!r}: one of {', '.join(STEERING_MODELS)}")
    raise ExportError(f"unknown model {model!r}: an FMU is exported of one of {', '.join(MODELS)}")


# -- model description -------------------------------------------------------------------------


def _number(value: float | int) -> str:
    return str(value) if isinstance(value, int) else repr(float(value))


def token_of(spec: ModelSpec, fmi_version: int) -> str:
    """A GUID-shaped token of everything the binary and the description must agree on."""
    digest = hashlib.sha256(
        repr((__version__, fmi_version, spec.identifier, spec.variables, spec.defaults)).encode()
    ).hexdigest()
    return f"{{{digest[:8]}-{digest[8:12]}-{digest[12:16]}-{digest[16:20]}-{digest[20:32]}}}"


def _value_reference(index: int) -> int:
    """Variables are numbered 1..n in order (FMI 3's time is 0)."""
    return index + 1


def model_description(spec: ModelSpec, fmi_version: int, token: str) -> str:
    """modelDescription.xml of the FMU, FMI 2.0 or 3.0."""
    if fmi_version not in FMI_VERSIONS:
        raise ExportError(f"FMI version {fmi_version}: choose 2 or 3")
    fmi3 = fmi_version == 3
    root = ET.Element("fmiModelDescription")
    root.set("fmiVersion", "3.0" if fmi3 else "2.0")
    root.set("modelName", spec.title)
    root.set("instantiationToken" if fmi3 else "guid", token)
    root.set("description", spec.description)
    root.set("generationTool", f"carfeel {__version__}")
    root.set("version", __version__)
    root.set("variableNamingConvention", "structured")
    if not fmi3:
        root.set("numberOfEventIndicators", "0")
    cs = ET.SubElement(root, "CoSimulation")
    cs.set("modelIdentifier", spec.identifier)
    cs.set("canHandleVariableCommunicationStepSize", "true")
    if fmi3:
        cs.set("canGetAndSetFMUState", "true")
        cs.set("canSerializeFMUState", "true")
        cs.set("hasEventMode", "false")
    else:
        cs.set("canGetAndSetFMUstate", "true")
        cs.set("canSerializeFMUstate", "true")
        cs.set("canNotUseMemoryManagementFunctions", "true")
        files = ET.SubElement(cs, "SourceFiles")
        for name in source_files(spec, 2):
            if name.endswith(".c"):
                ET.SubElement(files, "File").set("name", name)
    units = sorted({v.unit for v in spec.variables if v.unit} | ({"s"} if fmi3 else set()))
    if units:
        definitions = ET.SubElement(root, "UnitDefinitions")
        for unit in units:
            name, base = _FMI_UNITS[unit]
            element = ET.SubElement(definitions, "Unit", name=name)
            ET.SubElement(element, "BaseUnit", {k: str(v) for k, v in base.items()})
    types = ET.SubElement(root, "TypeDefinitions") if spec.enumerations else root
    for type_name, items in spec.enumerations:
        if fmi3:
            enum = ET.SubElement(types, "EnumerationType", name=type_name)
        else:
            enum = ET.SubElement(ET.SubElement(types, "SimpleType", name=type_name), "Enumeration")
        for value, (item, doc) in enumerate(items):
            ET.SubElement(enum, "Item", name=item, value=str(value), description=doc)
    categories = ET.SubElement(root, "LogCategories")
    for name, doc in (
        ("logStatusError", "errors: bad values, calls out of order, refused steps"),
        ("logStatusWarning", "warnings"),
    ):
        ET.SubElement(categories, "Category", name=name, description=doc)
    ET.SubElement(
        root, "DefaultExperiment", startTime="0.0", stopTime="10.0", stepSize=repr(MODEL_STEP_S)
    )
    variables = ET.SubElement(root, "ModelVariables")
    if fmi3:
        ET.SubElement(
            variables, "Float64", name="time", valueReference="0", causality="independent",
            variability="continuous", description="Simulation time", unit="s",
        )  # fmt: skip
    for index, v in enumerate(spec.variables):
        attributes = {
            "name": v.name,
            "valueReference": str(_value_reference(index)),
            "description": v.description,
            "causality": v.causality,
            "variability": v.variability,
        }
        typed: dict[str, str] = {}
        if v.start is not None:
            typed["start"] = _number(v.start)
        if v.unit:
            typed["unit"] = fmi_unit(v.unit)
        # FMI's min and max are inclusive: an open bound is the next value inside it.
        low, high = v.low, v.high
        if v.is_real and not v.low_inclusive:
            low = math.nextafter(low, math.inf)
        if v.is_real and not v.high_inclusive:
            high = math.nextafter(high, -math.inf)
        if v.kind == "integer" and math.isfinite(high):
            high = min(high, INTEGER_MAX[fmi_version])  # FMI 2's Integer is 32 bits
        if math.isfinite(low) and v.kind in ("real", "integer"):
            typed["min"] = _number(low if v.is_real else int(low))
        if math.isfinite(high) and v.kind in ("real", "integer"):
            typed["max"] = _number(high if v.is_real else int(high))
        enumerated = v.kind not in ("real", "integer")
        if enumerated:
            typed["declaredType"] = v.kind
        if fmi3:
            tag = "Float64" if v.is_real else ("Enumeration" if enumerated else v.fmi3_integer)
            ET.SubElement(variables, tag, {**attributes, **typed})
        else:
            scalar = ET.SubElement(variables, "ScalarVariable", attributes)
            tag = "Real" if v.is_real else ("Enumeration" if enumerated else "Integer")
            ET.SubElement(scalar, tag, typed)
    structure = ET.SubElement(root, "ModelStructure")
    outputs = [(i, v) for i, v in enumerate(spec.variables) if v.causality == "output"]
    if fmi3:
        # No output changes with an input before the next step: no direct dependencies.
        for i, _ in outputs:
            ET.SubElement(structure, "Output", valueReference=str(_value_reference(i)),
                          dependencies="")  # fmt: skip
        for i, _ in outputs:
            ET.SubElement(structure, "InitialUnknown", valueReference=str(_value_reference(i)))
    else:
        listed = ET.SubElement(structure, "Outputs")
        for i, _ in outputs:
            ET.SubElement(listed, "Unknown", index=str(i + 1), dependencies="")
        initial = ET.SubElement(structure, "InitialUnknowns")
        for i, _ in outputs:
            ET.SubElement(initial, "Unknown", index=str(i + 1))
    ET.indent(root)
    text: str = ET.tostring(root, encoding="unicode", xml_declaration=False)
    document = '<?xml version="1.0" encoding="UTF-8"?>\n' + text + "\n"
    try:  # a strict parser (expat) reads it back: an importer must be able to
        ET.fromstring(document.encode("utf-8"))
    except ET.ParseError as exc:  # pragma: no cover - checked_name keeps the text well-formed
        raise ExportError(
            f"the model description is not well-formed XML ({exc}): this is a bug in carfeel's "
            "FMU export; please report it"
        ) from None
    return document


def build_description(spec: ModelSpec) -> str:
    """sources/buildDescription.xml of an FMI 3 FMU: what to compile, and how."""
    root = ET.Element("fmiBuildDescription", fmiVersion="3.0")
    config = ET.SubElement(root, "BuildConfiguration", modelIdentifier=spec.identifier)
    files = ET.SubElement(
        config, "SourceFileSet", language="C99", compiler="gcc",
        compilerOptions=" ".join(flag for flag in CFLAGS if not flag.startswith("-W")),
    )  # fmt: skip
    for name in source_files(spec, 3):
        if name.endswith(".c"):
            ET.SubElement(files, "SourceFile", name=name)
    ET.SubElement(config, "Library", name="m")
    ET.indent(root)
    text: str = ET.tostring(root, encoding="unicode")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + text + "\n"


# -- C sources ---------------------------------------------------------------------------------


def source_files(spec: ModelSpec, fmi_version: int) -> tuple[str, ...]:
    """The files of the FMU's sources/ folder (generated and FMI headers included)."""
    model = spec.source_file
    ports = [name for stem in spec.ports for name in (f"{stem}.c", f"{stem}.h")]
    wrapper = f"cf_fmi{fmi_version}.c"
    return (
        *ports, model, model.replace(".c", ".h"), "cf_fmu.c", "cf_fmu.h", wrapper,
        "cf_generated.c", *HEADERS[fmi_version],
    )  # fmt: skip


_C_PLAIN = frozenset(
    b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789 _.,:;+-=()[]{}"
)
"""Bytes a generated C string literal holds as they are; every other is an octal escape."""


def c_string(text: str) -> str:
    """`text` as a C99 string literal of its UTF-8 bytes: each byte outside `_C_PLAIN` as a
    three-digit octal escape. So no quote, backslash, newline or comment marker can end the
    literal, no `??/` trigraph (gcc's -std=c99 reads them) can escape its quote, and no escape
    runs on into the next character (a hex escape would: "\\x41B" is one byte)."""
    return (
        '"' + "".join(chr(b) if b in _C_PLAIN else f"\\{b:03o}" for b in text.encode("utf-8")) + '"'
    )


def _c_number(value: float | int) -> str:
    if isinstance(value, float) and math.isnan(value):
        raise ExportError("a NaN parameter value reached the C source: this is a bug in carfeel")
    if isinstance(value, int):
        # -2^63 has no literal: 9223372036854775808 does not fit a long long.
        return "(-9223372036854775807LL - 1)" if value == -(2**63) else f"{value}LL"
    if math.isinf(value):
        return "INFINITY" if value > 0 else "-INFINITY"
    return repr(float(value))


def generated_c(spec: ModelSpec, token: str) -> str:
    """cf_generated.c: the table of variables and the preset's values."""
    header = spec.source_file.replace(".c", ".h")
    # User text (the preset's name) is data here, never code: an escaped string literal only,
    # never in a comment or a preprocessor line. Everything else is carfeel's own text.
    lines = [
        f"/* Generated by carfeel export fmu {spec.model}: the variables of modelDescription.xml",
        " * (value references 1..n, in order) and the preset's values (cf_preset names it).",
        " * Regenerate rather than edit. */",
        "#include <math.h>",
        "#include <stddef.h>",
        "",
        f'#include "{header}"',
        "",
        f"const char cf_token[] = {c_string(token)};",
        f"const char cf_preset[] = {c_string(spec.preset)};",
        f"const char cf_carfeel_version[] = {c_string(__version__)};",
        "const size_t cf_model_size = sizeof(struct cf_model);",
        "",
        "const cf_variable cf_variables[] = {",
    ]
    causality = {"parameter": "CF_PARAMETER", "input": "CF_INPUT", "output": "CF_OUTPUT"}
    variability = {
        "fixed": "CF_FIXED", "tunable": "CF_TUNABLE", "continuous": "CF_CONTINUOUS",
        "discrete": "CF_DISCRETE",
    }  # fmt: skip
    for index, v in enumerate(spec.variables):
        kind = "CF_REAL" if v.is_real else "CF_INTEGER"
        lines.append(
            f"    {{{_value_reference(index)}, {kind}, {causality[v.causality]}, "
            f"{variability[v.variability]}, offsetof(struct cf_model, {v.c_member}), "
            f"{_c_number(float(v.low))}, {_c_number(float(v.high))}, {int(v.low_inclusive)}, "
            f"{int(v.high_inclusive)}, {c_string(v.name)}, {c_string(v.unit)}}},"
        )
    lines += [
        "};",
        f"const size_t cf_variable_count = {len(spec.variables)};",
        "",
        "void cf_model_defaults(struct cf_model *m) {",
        "    cf_model_clear(m);",
    ]
    starts = [(v.c_member, v.start) for v in spec.variables if v.start is not None]
    for member, value in [*spec.defaults, *starts]:
        assert value is not None
        number = value if isinstance(value, int) else float(value)
        lines.append(f"    m->{member} = {_c_number(number)};")
    lines += ["}", ""]
    return "\n".join(lines)


def c_source_dir() -> Path:
    """Where carfeel's C sources are installed."""
    return Path(str(resources.files("carfeel.export").joinpath("c")))


def fmi_header_dir() -> Path:
    """The FMI headers FMPy ships (its c-code folder); ExportError naming the extra without it."""
    spec = importlib.util.find_spec("fmpy")
    if spec is None or spec.origin is None:
        raise ExportError(
            "FMU export takes the standard FMI headers from FMPy, which is not installed: "
            "pip install 'carfeel[fmu]'"
        )
    folder = Path(spec.origin).parent / "c-code"
    missing = [h for v in FMI_VERSIONS for h in HEADERS[v] if not (folder / h).is_file()]
    if missing:
        raise ExportError(
            f"the installed FMPy ({folder}) lacks the FMI headers {', '.join(missing)}: "
            "reinstall it with pip install --force-reinstall 'carfeel[fmu]'"
        )
    return folder


def find_compiler() -> str:
    """The C compiler ($CC, else cc or gcc); ExportError naming the package to install."""
    wanted = os.environ.get("CC")
    for name in ([wanted] if wanted else []) + ["cc", "gcc"]:
        found = shutil.which(name)
        if found:
            return found
    raise ExportError(
        "no C compiler found (looked for "
        + (f"$CC={wanted}, " if wanted else "")
        + "cc and gcc): install the distribution's gcc package (Debian and Ubuntu: "
        "apt-get install gcc; Fedora: dnf install gcc) or set CC to a C99 compiler"
    )


def check_platform() -> None:
    """The binaries are built for Linux x86-64; elsewhere ExportError says so."""
    system, machine = platform.system(), platform.machine().lower()
    if system != "Linux" or machine not in ("x86_64", "amd64"):
        raise ExportError(
            f"FMU binaries are built for Linux x86-64 only; this is {system} {machine}. "
            "Export on a Linux x86-64 machine (the FMU's sources/ build elsewhere too)"
        )


def compile_library(compiler: str, folder: Path, sources: Sequence[str], library: Path) -> None:
    """Compile `sources` (in `folder`) into the shared library `library`."""
    command = [
        compiler, *CFLAGS, "-shared", "-I", str(folder), "-o", str(library),
        *(str(folder / s) for s in sources), "-lm",
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise ExportError(
            f"the C compiler failed ({' '.join(command)}):\n{done.stderr.strip()}\n"
            "this is a bug in carfeel's FMU export or an unusual compiler: please report it"
        )
    if done.stderr.strip():
        raise ExportError(f"the C compiler warned, which carfeel's sources must not make it do:\n"
                          f"{done.stderr.strip()}")  # fmt: skip


BUILDERS = ("auto", "gcc", "cmake")
"""How the FMU's binary is built: gcc (the C compiler called directly: Linux x86-64), cmake
(FMPy's CMake build of the FMU's own sources/: Windows with Visual Studio or MinGW, macOS,
Linux), auto (gcc where it applies, else cmake)."""


def choose_builder(builder: str) -> str:
    """The builder to use here (see BUILDERS); ExportError naming what to install."""
    if builder not in BUILDERS:
        raise ExportError(f"--build {builder!r}: choose one of {', '.join(BUILDERS)}")
    system, machine = platform.system(), platform.machine().lower()
    linux64 = system == "Linux" and machine in ("x86_64", "amd64")
    if builder == "auto":
        has_cc = any(shutil.which(n) for n in (os.environ.get("CC") or "", "cc", "gcc") if n)
        if linux64 and not has_cc and shutil.which("cmake") is None:
            find_compiler()  # names the compiler to install (the fast path here)
        builder = "gcc" if linux64 and has_cc else "cmake"
    if builder == "cmake" and shutil.which("cmake") is None:
        raise ExportError(
            "FMPy's CMake build needs cmake on the PATH (pip install cmake, or the system's "
            "package), and a C compiler it finds (Visual Studio's Build Tools on Windows, "
            "Xcode's command line tools on macOS, gcc on Linux)"
        )
    return builder


def cmake_flags() -> str:
    """The compiler flags that keep the C port's arithmetic Python's (no contraction into fused
    multiply-adds, no fast math, libm's functions as called), for CMake's C compiler."""
    if platform.system() == "Windows":
        return "/fp:strict"
    return " ".join(f for f in CFLAGS if f.startswith("-f"))


def export_fmu(spec: ModelSpec, fmi_version: int, out: Path, builder: str = "auto") -> list[str]:
    """Build the FMU of `spec` into the file `out` (written in one piece: a zip archive), its
    binary by `builder` (BUILDERS).

    Returns the files it holds. Raises ExportError when the platform, the compiler or FMPy's
    headers are missing, before anything is written."""
    if fmi_version not in FMI_VERSIONS:
        raise ExportError(f"FMI version {fmi_version}: choose 2 or 3")
    builder = choose_builder(builder)
    compiler = ""
    if builder == "gcc":
        check_platform()
        compiler = find_compiler()
    headers = fmi_header_dir()
    token = token_of(spec, fmi_version)
    ours = c_source_dir()
    with tempfile.TemporaryDirectory(prefix="carfeel-fmu-") as scratch:
        root = Path(scratch)
        sources = root / "sources"
        sources.mkdir()
        for name in source_files(spec, fmi_version):
            if name == "cf_generated.c":
                (sources / name).write_text(generated_c(spec, token), encoding="utf-8")
            elif name in HEADERS[fmi_version]:
                shutil.copyfile(headers / name, sources / name)
            else:
                shutil.copyfile(ours / name, sources / name)
        if fmi_version == 3:
            (sources / "buildDescription.xml").write_text(build_description(spec), "utf-8")
        (root / "modelDescription.xml").write_text(
            model_description(spec, fmi_version, token), encoding="utf-8"
        )
        if builder == "gcc":
            binaries = root / "binaries" / PLATFORM_FOLDER[fmi_version]
            binaries.mkdir(parents=True)
            c_files = [n for n in source_files(spec, fmi_version) if n.endswith(".c")]
            compile_library(compiler, sources, c_files, binaries / f"{spec.identifier}.so")
        else:
            cmake_build(root)
        documentation = root / "documentation"
        documentation.mkdir()
        main_page = "index.html" if fmi_version == 3 else "_main.html"  # each standard's name
        (documentation / main_page).write_text(_documentation(spec, fmi_version), "utf-8")
        return _zip(root, out)


def cmake_build(root: Path) -> None:
    """FMPy's CMake build of the staged FMU folder `root` (its sources/ and model description)
    into its binaries/ folder for this platform."""
    try:
        import fmpy.build
    except ImportError:
        raise ExportError(
            "FMPy's CMake build is missing: pip install 'carfeel[fmu]' (FMPy 0.3.20 or newer)"
        ) from None
    cmake = shutil.which("cmake") or "cmake"
    project = (Path(fmpy.build.__file__).parent / "c-code").as_posix()
    with tempfile.TemporaryDirectory(prefix="carfeel-cmake-") as build:
        # FMPy's settings (sources, target folder per platform, the model's identifier), and
        # CMake run here with its output kept: shown only when it fails.
        fmpy.build.create_cmake_settings(
            root, build, cmake_options={"CMAKE_C_FLAGS:STRING": cmake_flags()}
        )
        for command in (
            [cmake, "-S", project, "-B", build],
            [cmake, "--build", build, "--target", "install", "--config", "Release"],
        ):
            done = subprocess.run(command, capture_output=True, text=True, check=False)
            if done.returncode != 0:
                raise ExportError(
                    f"FMPy's CMake build of the FMU failed ({' '.join(command)}):\n"
                    f"{(done.stdout + done.stderr).strip()[-3000:]}\nA C compiler CMake finds "
                    "is needed (Visual Studio's Build Tools on Windows, Xcode's command line "
                    "tools on macOS, gcc on Linux)"
                )
    if not any((root / "binaries").rglob("*.*")):
        raise ExportError("FMPy's CMake build produced no binary: this is a bug, please report it")


def _zip(root: Path, out: Path) -> list[str]:
    names = sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name in names:
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = (0o755 if name.endswith(".so") else 0o644) << 16
            archive.writestr(info, (root / name).read_bytes())
    return names


def _documentation(spec: ModelSpec, fmi_version: int) -> str:
    from html import escape

    rows = "\n".join(
        f"<tr><td>{escape(v.name)}</td><td>{v.causality}</td><td>{escape(v.unit)}</td>"
        f"<td>{'' if v.start is None else escape(_number(v.start))}</td>"
        f"<td>{escape(v.description)}</td></tr>"
        for v in spec.variables
    )
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>{escape(spec.title)}</title></head><body>
<h1>{escape(spec.title)}</h1>
<p>{escape(spec.description)}</p>
<p>FMI {fmi_version}.0 co-simulation, exported by carfeel {escape(__version__)} from the preset
{escape(spec.preset)}. Each communication step is a whole number of model steps
(<code>model_step_s</code>) with the inputs held over it; any other step is refused. An output
reflects the inputs set before the step that computed it: an importer sees the effect of an
input one communication step later.</p>
<table border="1"><tr><th>name</th><th>causality</th><th>unit</th><th>start</th>
<th>description</th></tr>
{rows}
</table></body></html>
"""


def build_port_library(folder: Path) -> Path:
    """The C ports alone (cf_engagement.c, cf_steering.c) as a shared library in `folder`,
    compiled as the FMUs are: for driving the C step from Python (tests, benchmarks)."""
    library = folder / "carfeel_port.so"
    compile_library(find_compiler(), c_source_dir(), PORT_SOURCES, library)
    return library


# The dataclasses whose flat layout the C structs mirror (tests check the field order).
C_STRUCTS = {
    "cf_stage_mechanics": StageMechanics,
    "cf_detent_params": DetentParams,
    "cf_chamfer_params": ChamferParams,
    "cf_engagement_params": EngagementParams,
    "cf_torque_params": SteeringTorqueParams,
    "cf_vehicle_params": VehicleParams,
    "cf_tyre_params": TyreParams,
    "cf_system_params": SystemParams,
}
