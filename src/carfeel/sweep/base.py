"""The preset a sweep starts from, as parameters: validated as `carfeel.io.presets` validates
it, kept per process; an H-pattern's tables with its engagement preset (`HPatternCase`)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

from carfeel.errors import PresetError
from carfeel.io import presets
from carfeel.models.drivers.hpattern import HPatternDriverParams
from carfeel.models.gearshift.hpattern import FeelParams, Layout, SelectParams, WallParams
from carfeel.models.gearshift.synchronizer import SynchronizerParams
from carfeel.simulation.hpattern import HPatternSetup
from carfeel.simulation.shift import ShiftParams


@dataclass(frozen=True, slots=True)
class HPatternCase:
    """What an H-pattern sweep varies: the preset's tables (its key paths as in the preset
    file) and its engagement preset (under `shift.`)."""

    layout: Layout
    select: SelectParams
    walls: WallParams
    synchronizer: SynchronizerParams
    feel: FeelParams
    driver: HPatternDriverParams
    shift: ShiftParams

    @property
    def setup(self) -> HPatternSetup:
        return HPatternSetup(
            self.layout, self.select, self.walls, self.synchronizer, self.feel, self.driver
        )


@lru_cache(maxsize=8)
def base_params(model: str, preset_text: str, engagement_text: str = "") -> Any:
    """The preset's parameters (validated as `carfeel.io.presets` does), from its text."""
    if model == "shift":
        return presets.from_toml("shift", "preset", preset_text).params
    if model == "steering":
        return presets.from_toml("steering", "preset", preset_text).params
    shift = presets.from_toml("shift", "engagement", engagement_text).params
    data = presets.parse("preset", preset_text)
    problems: list[str] = []
    tables = {k: v for k, v in data.items() if k not in ("name", "source", "engagement")}
    setup = presets.build(HPatternSetup, tables, "", problems)
    if setup is None or problems:
        raise PresetError("not valid:\n  " + "\n  ".join(problems))
    problems = presets.check_hpattern(setup, shift)
    if problems:
        raise PresetError("not valid:\n  " + "\n  ".join(problems))
    return HPatternCase(
        setup.layout,
        setup.select,
        setup.walls,
        setup.synchronizer,
        setup.feel,
        setup.driver,
        shift,
    )
