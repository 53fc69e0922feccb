"""carfeel: the feel of a car's primary controls (steering wheel, manual gearshift) from physics.

    import carfeel as cf
    result = cf.simulate_shift("paper-first-gear")
    print(cf.shift_features(result).synchronization_force_N)

The public API is the names in `__all__` (`carfeel.api` documents them on one page); they are
imported when first used, so `import carfeel` stays light (no numpy until a model runs).
"""

from __future__ import annotations

from importlib import import_module
from importlib.metadata import PackageNotFoundError, version
from typing import TYPE_CHECKING, Any

try:
    __version__ = version("carfeel")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0"

_EXPORTS = {
    # simulate, offline
    "simulate_shift": "carfeel.api",
    "simulate_hpattern": "carfeel.api",
    "simulate_steering": "carfeel.api",
    "shift_features": "carfeel.api",
    "steering_feel": "carfeel.api",
    "Result": "carfeel.simulation.result",
    "MANOEUVRES": "carfeel.simulation.manoeuvres",
    # presets
    "preset_names": "carfeel.api",
    "load_shift_preset": "carfeel.io.presets:load_shift",
    "load_steering_preset": "carfeel.io.presets:load_steering",
    "load_hpattern_preset": "carfeel.io.presets:load_hpattern",
    "Preset": "carfeel.io.presets",
    # the 1 kHz loop on a device
    "RealtimeRun": "carfeel.realtime.session",
    "RealtimeResult": "carfeel.realtime.session",
    "run_device": "carfeel.api",
    # identification
    "fit_steering": "carfeel.api",
    "fit_physical": "carfeel.api",
    "fit_shift": "carfeel.api",
    "validate_steering": "carfeel.api",
    # sweeps and FMUs
    "run_sweep": "carfeel.api",
    "export_fmu": "carfeel.api",
    # errors
    "CarfeelError": "carfeel.errors",
    "InputError": "carfeel.errors",
    "PresetError": "carfeel.errors",
}

__all__ = [
    "MANOEUVRES",
    "CarfeelError",
    "InputError",
    "Preset",
    "PresetError",
    "RealtimeResult",
    "RealtimeRun",
    "Result",
    "__version__",
    "export_fmu",
    "fit_physical",
    "fit_shift",
    "fit_steering",
    "load_hpattern_preset",
    "load_shift_preset",
    "load_steering_preset",
    "preset_names",
    "run_device",
    "run_sweep",
    "shift_features",
    "simulate_hpattern",
    "simulate_shift",
    "simulate_steering",
    "steering_feel",
    "validate_steering",
]
"""The public API; `_EXPORTS` says where each name lives (tests/test_public_api.py keeps the two
equal)."""

if TYPE_CHECKING:
    from carfeel.api import (
        export_fmu,
        fit_physical,
        fit_shift,
        fit_steering,
        preset_names,
        run_device,
        run_sweep,
        shift_features,
        simulate_hpattern,
        simulate_shift,
        simulate_steering,
        steering_feel,
        validate_steering,
    )
    from carfeel.errors import CarfeelError, InputError, PresetError
    from carfeel.io.presets import Preset
    from carfeel.io.presets import load_hpattern as load_hpattern_preset
    from carfeel.io.presets import load_shift as load_shift_preset
    from carfeel.io.presets import load_steering as load_steering_preset
    from carfeel.realtime.session import RealtimeResult, RealtimeRun
    from carfeel.simulation.manoeuvres import MANOEUVRES
    from carfeel.simulation.result import Result


def __getattr__(name: str) -> Any:
    """The public names, imported on first use (PEP 562)."""
    target = _EXPORTS.get(name)
    if target is None:
        raise AttributeError(f"module 'carfeel' has no attribute {name!r}")
    module, _, attribute = target.partition(":")
    value = getattr(import_module(module), attribute or name)
    globals()[name] = value  # the next use is a plain lookup
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])
