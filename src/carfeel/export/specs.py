"""The FMUs' specs: the shift FMU (the engagement), the steering FMU (the paper's torque law or
the physical model), each from a preset; `spec_for` picks one by the command line's names.
"""

from __future__ import annotations

from carfeel.export.variables import (
    MODEL_STEP_S,
    ExportError,
    ModelSpec,
    Variable,
    checked_name,
    flatten,
    model_step,
    preset_values,
    signed_seed,
    table_parameters,
)
from carfeel.io.force_profile import MAX_FORCE_N
from carfeel.io.presets import STEERING_STEP_S as PHYSICAL_MAX_STEP_S
from carfeel.io.presets import Preset
from carfeel.models.gearshift.engagement import EngagementParams, Stage
from carfeel.schema import unit_of
from carfeel.simulation.shift import MAX_STEP_S as SHIFT_MAX_STEP_S
from carfeel.simulation.shift import ShiftParams
from carfeel.simulation.steering import MAX_STEP_S as STEERING_MAX_STEP_S
from carfeel.simulation.steering import SteeringCar

MODELS = ("steering", "shift")
STEERING_MODELS = ("paper", "physical")
"""The steering FMU's model: the paper's law, or the physical model (`--steering-model`)."""

AY_SOURCES = ("input", "vehicle", "front_axle", "steady_state")
"""Where the steering FMU's tau0 takes Ay from (its parameter ay_source), in the C enum's order."""


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


def _shift_variables(gearbox: EngagementParams, seed: int) -> list[Variable]:
    """The shift FMU's variables: inputs, the gearbox's parameters, seed, step, outputs."""
    real = "real"
    return [
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
        *table_parameters("gearbox", gearbox),
        Variable("seed", "parameter", "fixed", "integer", "seed",
                 "Seed of the tooth draws (SplitMix64): the relative tooth angle of each "
                 "engagement; one seed gives one result, as carfeel's --seed N for N >= 0, "
                 "and N + 2^64 for N < 0 (FMI 2's 32-bit Integer reaches the seeds below 2^31 "
                 "and from 2^64 - 2^31; FMI 3's Int64 all)", signed_seed(seed),
                 fmi3_integer="Int64"),
        model_step(SHIFT_MAX_STEP_S, "at most carfeel's shift step, where a hand closing the "
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


def shift_spec(preset: Preset[ShiftParams], seed: int = 0) -> ModelSpec:
    """The shift FMU: the 1-DOF engagement of `preset`'s gearbox, driven by a knob force."""
    gearbox = preset.params.gearbox
    name = checked_name(preset.name)
    variables = _shift_variables(gearbox, seed)
    defaults = preset_values("gearbox", gearbox)
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


def _steering_variables(car: SteeringCar) -> list[Variable]:
    """The paper's law's variables: inputs, the torque law's and the car's parameters, the
    source of Ay, the step, outputs."""
    real = "real"
    return [
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
        *table_parameters("torque", car.torque),
        *table_parameters("vehicle", car.vehicle, _VEHICLE_USED),
        Variable("ay_source", "parameter", "fixed", "AySource", "ay_source",
                 "Where tau0 takes Ay from: " + "; ".join(
                     f"{name} = {i}: {doc}" for i, (name, doc) in
                     enumerate(zip(AY_SOURCES, _AY_DOCS, strict=True))), 0,
                 low=0, high=len(AY_SOURCES) - 1),
        model_step(STEERING_MAX_STEP_S, "the car's trapezoidal step (with ay_source vehicle or "
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


def steering_spec(preset: Preset[SteeringCar]) -> ModelSpec:
    """The steering FMU: the paper's torque law of `preset`'s car, Ay from the importer or the
    FMU's single-track car."""
    car = preset.params
    name = checked_name(preset.name)
    variables = _steering_variables(car)
    defaults = preset_values("torque", car.torque) + preset_values("vehicle", car.vehicle)
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
    used = tuple(p for p, _, _, _ in flatten(car.vehicle) if p != "width_m")
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
        *table_parameters("vehicle", car.vehicle, used, "params.vehicle"),
        *table_parameters("tyres", car.tyres, None, "params.tyres"),
        *table_parameters(
            "steering_system", car.steering_system, None, "params.system"
        ),
        model_step(PHYSICAL_MAX_STEP_S, "the preset's checks size the steering system for "
                   "1 ms (semi-implicit Euler)"),
        *(Variable(name, "output", "continuous", real, f"outputs.{member}", doc,
                   unit=unit_of(name)) for name, member, doc in _PHYSICAL_OUTPUTS),
    ]  # fmt: skip
    defaults = [
        *preset_values("params.vehicle", car.vehicle),
        *preset_values("params.tyres", car.tyres),
        *preset_values("params.system", car.steering_system),
    ]
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
