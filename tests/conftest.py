"""Shared fixtures: the default preset and one simulated shift per seed (cached per session)."""

from __future__ import annotations

import dataclasses
import functools

import pytest

from carfeel.io.presets import load_shift
from carfeel.simulation.result import Result
from carfeel.simulation.shift import ShiftParams, simulate_shift

# Recordings the tests use live in tests/data (tests.datafiles.data_file): nothing here reads
# ../shared or a machine path.


@functools.cache
def default_params() -> ShiftParams:
    return load_shift("paper-first-gear").params


@functools.cache
def shift_run(seed: int = 0, substeps: int = 1, pull_out: bool = False) -> Result:
    params = default_params()
    if pull_out:
        params = dataclasses.replace(
            params, driver=dataclasses.replace(params.driver, pull_out=True)
        )
    duration = 2.0 if pull_out else 1.2
    return simulate_shift(params, seed=seed, duration_s=duration, substeps=substeps)


@pytest.fixture
def params() -> ShiftParams:
    return default_params()


@pytest.fixture(autouse=True, scope="session")
def _device_profiles(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Device profiles go to a folder of the test run, never the user's configuration (the
    runs of one session share it, as a user's runs share theirs)."""
    import os

    os.environ["CARFEEL_CONFIG_DIR"] = str(tmp_path_factory.mktemp("carfeel-config"))
