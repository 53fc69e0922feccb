"""Which parameter moves each metric most: rank correlations over a sweep's rows.

Two indices per (metric, parameter), over the rows whose metric is a number:
- Spearman's rho: the correlation of the ranks. It measures a monotone effect whatever its
  shape or units (an engagement peak that grows with the gear's inertia like a square root still
  gives 1), is unbiased by a heavy tail, and needs no particular design: grids, random draws and
  Latin hypercubes all do.
- PRCC, the partial rank correlation (Saltelli & Marivoet 1990; Marino et al., J. Theor. Biol.
  2008): the correlation of the ranks of the parameter and of the metric, each with the linear
  effect of the other parameters' ranks removed. With several parameters varied together it
  isolates each one's own effect, where rho mixes in whatever the others do by chance.
Parameters are ranked by |PRCC| (|rho| when there is a single parameter, or too few rows).

Not chosen: a variance-based index (Sobol', eFAST) needs its own sampling design (Saltelli's
N (k + 2) runs, or eFAST's search curves), which grids and plain Monte Carlo draws are not; and
rank correlations assume a monotone effect: a metric with an optimum inside the range (a
U-shape) shows up with a small index, so the plot of the metric against each parameter is drawn
beside them. The seed (the tooth position) is noise to these indices: it lowers them all alike.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Index:
    parameter: str
    spearman: float
    prcc: float
    n: int

    @property
    def strength(self) -> float:
        """What the ranking uses: |PRCC|, or |rho| where there is no PRCC."""
        value = self.prcc if math.isfinite(self.prcc) else self.spearman
        return abs(value) if math.isfinite(value) else -1.0


def _ranks(values: F64) -> F64:
    """Ranks 1..n, ties sharing their mean rank."""
    n = len(values)
    order = np.argsort(values, kind="mergesort")
    where = np.empty(n, dtype=np.intp)
    where[order] = np.arange(n)
    ordered = values[order]
    starts = np.r_[True, ordered[1:] != ordered[:-1]]
    group = np.cumsum(starts)[where] - 1
    edges = np.r_[np.flatnonzero(starts), n]
    return np.asarray(0.5 * (edges[group] + edges[group + 1] - 1) + 1.0, dtype=float)


def _correlation(a: F64, b: F64) -> float:
    a, b = a - a.mean(), b - b.mean()
    scale = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b) / scale if scale > 0.0 else math.nan


def indices(parameters: Mapping[str, Any], metric: Any) -> list[Index]:
    """Spearman and PRCC of `metric` against each parameter, strongest first."""
    y = np.asarray(metric, dtype=float)
    names = list(parameters)
    x = (
        np.column_stack([np.asarray(parameters[n], dtype=float) for n in names])
        if names
        else (np.zeros((len(y), 0)))
    )
    keep = np.isfinite(y) & np.all(np.isfinite(x), axis=1)
    y, x = y[keep], x[keep]
    n = len(y)
    out = []
    if n < 3:
        return [Index(name, math.nan, math.nan, n) for name in names]
    ry = _ranks(y)
    rx = np.column_stack([_ranks(x[:, j]) for j in range(x.shape[1])])
    varied = [j for j in range(x.shape[1]) if np.ptp(x[:, j]) > 0.0]
    for j, name in enumerate(names):
        rho = _correlation(rx[:, j], ry) if j in varied and np.ptp(y) > 0.0 else math.nan
        prcc = math.nan
        others = [k for k in varied if k != j]
        if j in varied and np.ptp(y) > 0.0 and others and n > len(others) + 2:
            basis = np.column_stack([np.ones(n), rx[:, others]])
            res_x = rx[:, j] - basis @ np.linalg.lstsq(basis, rx[:, j], rcond=None)[0]
            res_y = ry - basis @ np.linalg.lstsq(basis, ry, rcond=None)[0]
            prcc = _correlation(res_x, res_y)
        elif j in varied and not others:
            prcc = rho
        out.append(Index(name, rho, prcc, n))
    return sorted(out, key=lambda i: -i.strength)


@dataclass(frozen=True)
class Summary:
    n: int
    mean: float
    sd: float
    p5: float
    p50: float
    p95: float


def summary(values: Any) -> Summary:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if not len(v):
        return Summary(0, *([math.nan] * 5))
    p5, p50, p95 = (float(q) for q in np.percentile(v, [5, 50, 95]))
    return Summary(
        len(v), float(v.mean()), float(v.std(ddof=1)) if len(v) > 1 else 0.0, p5, p50, p95
    )
