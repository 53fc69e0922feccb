"""What the physical steering model's fit (`physical_fit`) fits and gives: the fitted
parameters (`PARAMETERS`, their bounds and scales in the preset's tables), a car with them set
(`with_values`) and the result (`PhysicalFit`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.identification.steering_types import SteeringFit
from carfeel.simulation.steering import SteeringCar

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class PhysicalFit(SteeringFit):
    """A `SteeringFit` of the physical model, with what its simulations cost and how closely
    the batch matched the pure model."""

    batch_check_Nm: float = math.nan
    """Largest difference of the batch's residual from the pure model's at the solution."""
    sweeps: int = 0
    """Batches run (each over every piece that had to be simulated again)."""
    simulated_s: float = 0.0
    """Model time simulated in all, over every parameter set (s)."""

    def as_dict(self) -> dict[str, object]:
        return {
            **super().as_dict(),
            "simulation": {"batch_check_Nm": self.batch_check_Nm, "sweeps": self.sweeps,
                           "simulated_s": self.simulated_s},
        }  # fmt: skip


@dataclass(frozen=True)
class Parameter:
    """One fitted parameter: its table and field in the preset, bounds (the preset's ranges),
    and a scale (a typical size, for the finite differences)."""

    name: str
    table: str
    lower: float
    upper: float
    scale: float


PARAMETERS = (
    Parameter("assist_gain_standstill_1_Nm", "steering_system", 0.0, 20.0, 1.0),
    Parameter("assist_gain_high_speed_1_Nm", "steering_system", 0.0, 20.0, 0.1),
    Parameter("column_friction_Nm", "steering_system", 0.0, 10.0, 0.3),
    Parameter("rack_friction_Nm", "steering_system", 0.0, 20.0, 0.5),
    Parameter("eps_damping_high_speed_Nm_s_rad", "steering_system", 0.0, 10.0, 1.0),
    Parameter("pneumatic_trail_m", "tyres", 0.0, 0.1, 0.02),
    Parameter("friction_coefficient", "tyres", 0.05, 2.0, 0.5),
)
NAMES = tuple(p.name for p in PARAMETERS)
MEANINGS = {
    "assist_gain_standstill_1_Nm": "EPS boost gain parked: assist = gain (|torsion-bar torque| - "
    "deadband)^2, 1/Nm",
    "assist_gain_high_speed_1_Nm": "EPS boost gain at speed (the gain falls to it with speed), "
    "1/Nm",
    "column_friction_Nm": "Coulomb friction of the column, felt at the rim, Nm",
    "rack_friction_Nm": "Coulomb friction of the rack, at the pinion, Nm",
    "eps_damping_high_speed_Nm_s_rad": "EPS damping at speed (rises to it with speed), Nm s/rad",
    "pneumatic_trail_m": "the tyres' pneumatic trail at zero slip (collapses as they slide), m",
    "friction_coefficient": "the road's friction coefficient mu (dry about 1.0)",
}
"""What each fitted parameter is, for the report."""

LIMIT_G = 0.6
"""mu is seen only past about this lateral acceleration (the brush's trail collapses there)."""


def value_of(car: SteeringCar, parameter: Parameter) -> float:
    table = car.tyres if parameter.table == "tyres" else car.steering_system
    return float(getattr(table, parameter.name))


def with_values(car: SteeringCar, values: Sequence[float] | FloatArray) -> SteeringCar:
    """The car with PARAMETERS set to `values`."""
    assert car.tyres is not None and car.steering_system is not None
    tyres = {
        p.name: float(v) for p, v in zip(PARAMETERS, values, strict=True) if p.table == "tyres"
    }
    system = {p.name: float(v) for p, v in zip(PARAMETERS, values, strict=True)
              if p.table == "steering_system"}  # fmt: skip
    return dataclasses.replace(
        car,
        tyres=dataclasses.replace(car.tyres, **tyres),
        steering_system=dataclasses.replace(car.steering_system, **system),
    )
