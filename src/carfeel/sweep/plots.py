"""A sweep's figures and its HTML page: each metric's distribution, each metric against each
parameter, and the sensitivity ranking (`sweep.sensitivity`). matplotlib is imported lazily."""

from __future__ import annotations

import json
import math
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from carfeel.io import report
from carfeel.sweep import sensitivity
from carfeel.sweep.results import as_float

MAX_PLOTTED_ROWS = 100_000
"""Cases a sweep's figures are drawn from at most: beyond, every k-th case (a systematic
sample: the rank correlations of 10^5 cases are within 0.01 of all of them)."""
DISTRIBUTIONS = "distributions.png"
SENSITIVITY = "sensitivity.png"
PAGE = "index.html"


def safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "-" for c in name)


def every_for(n_cases: int) -> int:
    """Plot every k-th case of a sweep of `n_cases` (1: all of them)."""
    return 1 if n_cases <= MAX_PLOTTED_ROWS else math.ceil(n_cases / MAX_PLOTTED_ROWS)


def sampled_note(every: int, n_cases: int) -> str:
    return (f"drawn from every {every}th of the {n_cases} cases (at most {MAX_PLOTTED_ROWS} "
            "are plotted)")  # fmt: skip


def file_names(parameters: Sequence[str], metrics: Sequence[str]) -> list[str]:
    """Every file `write` makes, known before the sweep runs (so each can be staged)."""
    names = [DISTRIBUTIONS]
    if parameters:
        names += [SENSITIVITY, *(f"metric-{safe(m)}.png" for m in metrics)]
    return [*names, PAGE]


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _grid(n: int) -> tuple[int, int]:
    cols = min(n, 3)
    return math.ceil(n / cols), cols


def write(
    columns: Mapping[str, Sequence[Any]],
    meta: Mapping[str, str],
    staged: Mapping[str, Path],
    title: str,
) -> list[str]:
    """Draw every figure and the page into `staged` (final name -> where to write it now);
    returns the page's notes."""
    plt = _pyplot()
    parameters = json.loads(meta["carfeel_parameters"])
    described = json.loads(meta["carfeel_metrics"])
    metrics = list(described)
    ok = np.array([s == "ok" for s in columns["status"]], dtype=bool)
    values = {m: np.asarray(as_float(columns[m]))[ok] for m in metrics}
    params = {p: np.asarray(as_float(columns[p]))[ok] for p in parameters}
    statuses = list(columns["status"])
    notes = [
        f"{len(statuses)} cases: {statuses.count('ok')} ok, {statuses.count('invalid')} refused "
        f"by the preset validation, {statuses.count('failed')} failed"
    ]
    if "carfeel_plotted" in meta:
        notes.append(meta["carfeel_plotted"])

    rows, cols = _grid(len(metrics))
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.0 * rows), squeeze=False)
    for ax, name in zip(axes.flat, metrics, strict=False):
        v = values[name]
        finite = v[np.isfinite(v)]
        if name.endswith(("balked", "engaged", "ground")):
            share = float(finite.mean()) if len(finite) else math.nan
            ax.bar(["false", "true"], [1 - share, share], color=["#2ca02c", "#d62728"])
            ax.set_ylabel("share of cases")
        elif len(finite):
            ax.hist(finite, bins=min(40, max(5, int(math.sqrt(len(finite))))), color="#1f77b4")
            ax.set_ylabel("cases")
        ax.set_title(name, fontsize=9)
    for ax in list(axes.flat)[len(metrics) :]:
        ax.set_visible(False)
    fig.suptitle(f"{title}: distributions")
    fig.tight_layout()
    fig.savefig(staged[DISTRIBUTIONS], dpi=90)
    plt.close(fig)

    ranking: dict[str, list[sensitivity.Index]] = {}
    if parameters:
        for name in metrics:
            ranking[name] = sensitivity.indices(params, values[name])
            rows, cols = _grid(len(parameters))
            fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.0 * rows), squeeze=False)
            for ax, p in zip(axes.flat, parameters, strict=False):
                ax.plot(params[p], values[name], ".", ms=3, alpha=0.5, color="#1f77b4")
                index = next(i for i in ranking[name] if i.parameter == p)
                ax.set_xlabel(p, fontsize=8)
                ax.set_ylabel(name, fontsize=8)
                ax.set_title(
                    f"PRCC {report.number(index.prcc, 2)}, rho {report.number(index.spearman, 2)}",
                    fontsize=8,
                )
            for ax in list(axes.flat)[len(parameters) :]:
                ax.set_visible(False)
            fig.suptitle(f"{title}: {name}")
            fig.tight_layout()
            fig.savefig(staged[f"metric-{safe(name)}.png"], dpi=90)
            plt.close(fig)
        matrix = np.array(
            [
                [next(i for i in ranking[m] if i.parameter == p).prcc for p in parameters]
                for m in metrics
            ]
        )
        fig, ax = plt.subplots(figsize=(1.6 + 1.3 * len(parameters), 1.0 + 0.45 * len(metrics)))
        image = ax.imshow(np.nan_to_num(matrix), cmap="coolwarm", vmin=-1, vmax=1, aspect="auto")
        ax.set_xticks(range(len(parameters)), parameters, rotation=30, ha="right", fontsize=7)
        ax.set_yticks(range(len(metrics)), metrics, fontsize=7)
        for (r, c), value in np.ndenumerate(matrix):
            ax.text(c, r, report.number(value, 2), ha="center", va="center", fontsize=7)
        fig.colorbar(image, ax=ax, label="PRCC")
        ax.set_title(f"{title}: sensitivity (partial rank correlation)", fontsize=9)
        fig.tight_layout()
        fig.savefig(staged[SENSITIVITY], dpi=90)
        plt.close(fig)

    sections = [
        report.Section(
            "Sweep",
            [
                *notes,
                f"model {meta['carfeel_model']}, preset {meta['carfeel_preset']}, carfeel "
                f"{meta['carfeel_version']}; spec hash {meta['carfeel_spec_hash'][:12]}",
                "Spec: " + meta["carfeel_spec"],
            ],
        ),
        report.Section(
            "Metrics (cases with status ok)",
            table=[["metric", "n", "mean", "sd", "p5", "median", "p95", "what"]]
            + [
                [
                    m,
                    str(s.n),
                    report.number(s.mean),
                    report.number(s.sd),
                    report.number(s.p5),
                    report.number(s.p50),
                    report.number(s.p95),
                    described[m],
                ]
                for m in metrics
                for s in [sensitivity.summary(values[m])]
            ],
            figures=[Path(DISTRIBUTIONS)],
        ),
    ]
    if parameters:
        table = [["metric", "rank", "parameter", "PRCC", "Spearman rho", "n"]]
        for m in metrics:
            for k, index in enumerate(ranking[m], start=1):
                table.append(
                    [
                        m,
                        str(k),
                        index.parameter,
                        report.number(index.prcc, 3),
                        report.number(index.spearman, 3),
                        str(index.n),
                    ]
                )
        sections.append(
            report.Section(
                "Sensitivity: which parameter moves each metric most",
                [
                    "Ranked by |PRCC| (the partial rank correlation: each parameter's monotone "
                    "effect with the others' removed), Spearman's rank correlation beside it. "
                    "Rank correlations see monotone effects only: look at the metric against "
                    "each parameter for an optimum inside the range."
                ],
                table=table,
                figures=[Path(SENSITIVITY), *(Path(f"metric-{safe(m)}.png") for m in metrics)],
            )
        )
    with tempfile.TemporaryDirectory() as scratch:
        page = report.write(Path(scratch), title, sections)
        shutil.move(page, staged[PAGE])
    return notes
