"""What a sweep draws: its distributions sampled (random, or a Latin hypercube) block by block,
bit for bit the draws made at once, and its parameter sets (the grid's product times the
draws), made as they are asked for."""

from __future__ import annotations

import typing
from collections.abc import Iterator
from typing import Any

import numpy as np

from carfeel.sweep.definition import SweepSpec, Value

DRAW_BLOCK = 65_536
"""Parameter sets drawn at a time: a sweep's draws are made as its cases are, block by block."""


class Draws:
    """The draws of a spec's distributions, by sample index, made a block at a time: the same
    values as drawing all `samples` at once from numpy's PCG64 (plain: `rng.random((n, k))`;
    Latin: one permutation of n strata per parameter, then the uniforms), without holding them.
    A Latin hypercube keeps its strata (4 bytes per sample and parameter: 120 MB for 10^7
    samples of 3 parameters); plain draws keep nothing but the generator's state."""

    def __init__(self, spec: SweepSpec) -> None:
        self.vary = [v for v in spec.vary if v.distribution]
        self.samples = spec.samples
        rng = np.random.default_rng(spec.sampling_seed)
        self.strata: np.ndarray | None = None
        if self.vary and spec.sampling == "latin":  # one draw in each of `samples` strata
            self.strata = np.empty((spec.samples, len(self.vary)), dtype=np.int32)
            for j in range(len(self.vary)):
                self.strata[:, j] = rng.permutation(spec.samples)
        self.state: dict[str, Any] = dict(rng.bit_generator.state)
        """Where the uniforms start (after the permutations): each block advances from it."""

    def block(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Each varied path's draws of samples start..stop-1."""
        if not self.vary:
            return {}
        bits = np.random.PCG64()
        bits.state = typing.cast(Any, self.state)
        bits.advance(start * len(self.vary))  # one 64-bit output per uniform double
        u = np.random.Generator(bits).random((stop - start, len(self.vary)))
        if self.strata is not None:
            u = (self.strata[start:stop] + u) / self.samples
        return {v.path: v.sample(u[:, j]) for j, v in enumerate(self.vary)}


_DRAWS: dict[str, Draws] = {}


def draws_of(spec: SweepSpec) -> Draws:
    """The spec's Draws, made once per process (a worker's tasks of one sweep share them: a
    Latin hypercube's permutations of 10^7 strata take a second)."""
    draws = _DRAWS.get(spec.hash)
    if draws is None:
        _DRAWS.clear()  # one sweep at a time: the strata are 4 bytes a sample and parameter
        draws = _DRAWS[spec.hash] = Draws(spec)
    return draws


def iter_parameter_sets(spec: SweepSpec) -> Iterator[dict[str, Value]]:
    """Every parameter set, in order, made as it is asked for: the grid's product (spec order,
    the last key fastest) times the draws (the same `samples` draws at every grid point)."""
    for _, values in numbered_sets(spec, 0, spec.n_sets):
        yield dict(values)


def numbered_sets(
    spec: SweepSpec, first: int, stop: int
) -> Iterator[tuple[int, tuple[tuple[str, Value], ...]]]:
    """(index, values in the spec's order) of the parameter sets first..stop-1, made as they
    are asked for: each grid point's draws a block at a time (the blocks of DRAW_BLOCK samples
    the whole sweep draws, so a run of sets anywhere equals the same sets of the whole)."""
    grid = [v for v in spec.vary if v.values]
    sizes = [len(v.values) for v in grid]
    draws = draws_of(spec)
    index = first
    while index < stop:
        point, sample = divmod(index, spec.samples)
        fixed: dict[str, Value] = {}
        rest = point
        for v, size in zip(reversed(grid), reversed(sizes), strict=True):  # the last fastest
            rest, at = divmod(rest, size)
            fixed[v.path] = v.values[at]
        block = sample // DRAW_BLOCK * DRAW_BLOCK
        drawn = draws.block(block, min(block + DRAW_BLOCK, spec.samples))
        end = min(stop, point * spec.samples + min(block + DRAW_BLOCK, spec.samples))
        for i in range(index, end):
            s = i - point * spec.samples - block
            values = fixed | {path: float(column[s]) for path, column in drawn.items()}
            yield i, tuple((v.path, values[v.path]) for v in spec.vary)
        index = end


def parameter_sets(spec: SweepSpec) -> list[dict[str, Value]]:
    """Every parameter set as a list (small sweeps, tests); `iter_parameter_sets` makes them
    one at a time."""
    return list(iter_parameter_sets(spec))
