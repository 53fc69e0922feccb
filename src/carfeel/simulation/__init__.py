"""Fixed-step simulation in simulated time, and its Result."""

from carfeel.simulation.result import Result
from carfeel.simulation.runner import run

__all__ = ["Result", "run"]
