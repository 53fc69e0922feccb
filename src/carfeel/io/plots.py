"""Plots for reports. Results do not plot themselves; matplotlib is imported only here.

`plot_shift` draws what the paper shows for one engagement: force and position against time
(Fig. 5 and 9) and force against position (Fig. 6 and 11), with the stages marked.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from carfeel.errors import InputError
from carfeel.simulation.result import Result

MAX_LOOPS = 24
"""Engagements an H-pattern plot draws at most (its legend in two columns stays readable)."""

# One colour per stage, the same in every plot.
STAGE_COLOURS = {
    "neutral": "#9e9e9e",
    "synchronization": "#d62728",
    "gate_open": "#bcbd22",
    "engagement": "#ff7f0e",
    "free_travel": "#17becf",
    "stop": "#9467bd",
    "in_gear": "#2ca02c",
    "returning": "#8c564b",
}


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def stage_spans(stages: np.ndarray) -> list[tuple[str, int, int]]:
    """Runs of equal stage as (name, first index, last index + 1)."""
    spans: list[tuple[str, int, int]] = []
    start = 0
    for i in range(1, len(stages) + 1):
        if i == len(stages) or stages[i] != stages[start]:
            spans.append((str(stages[start]), start, i))
            start = i
    return spans


def plot_shift(result: Result, path: str | Path, title: str = "Gear engagement") -> Path:
    """Write a PNG of one (or more) engagements: force and position vs time, force vs position."""
    plt = _pyplot()
    t = result.time_s
    x_mm = result["position_m"] * 1e3
    force = result["force_N"]
    stages = result["stage"]
    spans = stage_spans(stages)

    fig = plt.figure(figsize=(13, 7.5), layout="constrained")
    grid = fig.add_gridspec(2, 2, width_ratios=[1.35, 1])
    ax_f = fig.add_subplot(grid[0, 0])
    ax_x = fig.add_subplot(grid[1, 0], sharex=ax_f)
    ax_fx = fig.add_subplot(grid[:, 1])

    for name, i0, i1 in spans:
        colour = STAGE_COLOURS.get(name, "#cccccc")
        t0 = t[i0] - (t[1] - t[0] if len(t) > 1 else 0.0)
        for ax in (ax_f, ax_x):
            ax.axvspan(t0, t[i1 - 1], color=colour, alpha=0.13, lw=0)
    ax_f.plot(t, force, color="k", lw=1.2)
    ax_f.set_ylabel("force at the knob [N]")
    ax_f.grid(alpha=0.3)
    ax_f.set_title(f"{title}: force and position vs time (cf. paper Fig. 5, 9)")
    ax_x.plot(t, x_mm, color="#1f77b4", lw=1.4)
    ax_x.set_ylabel("knob position [mm]")
    ax_x.set_xlabel("time [s]")
    ax_x.grid(alpha=0.3)

    _mark_peaks(ax_f, t, force, stages)

    for name, i0, i1 in spans:
        j0 = max(i0 - 1, 0)  # join each run to the one before so the loop has no gaps
        ax_fx.plot(x_mm[j0:i1], force[j0:i1], color=STAGE_COLOURS.get(name, "#888888"), lw=1.6)
    ax_fx.set_xlabel("knob position [mm]")
    ax_fx.set_ylabel("force at the knob [N]")
    ax_fx.set_title("force vs position (cf. paper Fig. 6, 11)")
    ax_fx.grid(alpha=0.3)

    seen = [name for name in STAGE_COLOURS if name in set(stages.tolist())]
    handles = [
        plt.Line2D([], [], color=STAGE_COLOURS[n], lw=6, alpha=0.6, label=n.replace("_", " "))
        for n in seen
    ]
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), frameon=False)
    return _save(fig, plt, path)


def _mark_peaks(ax: Any, t: np.ndarray, force: np.ndarray, stages: np.ndarray) -> None:
    labels = {
        "synchronization": "synchronization",
        "engagement": "engagement peak",
        "stop": "stop impact",
    }
    fig = ax.figure
    fig.canvas.draw()  # the layout, so that the labels can be placed in display units
    renderer = fig.canvas.get_renderer()
    trace = ax.transData.transform(np.column_stack([t, force]))
    frame = ax.get_window_extent(renderer)
    taken: list[tuple[float, float, float, float]] = []
    for name, label in labels.items():
        mask = stages == name
        if not mask.any():
            continue
        i = int(np.flatnonzero(mask)[np.argmax(force[mask])])
        text = f"{label}\n{force[i]:.1f} N"
        probe = ax.text(0.0, 0.0, text, fontsize=8)
        size = probe.get_window_extent(renderer)
        probe.remove()
        half_w, half_h = size.width / 2 + 4.0, size.height / 2 + 4.0
        anchor = trace[i]
        # Nearest place around the peak whose box holds no part of the trace, stays inside the
        # axes and clear of the labels placed before: the label never hides the curve.
        centre = anchor + np.array([half_w + 10.0, half_h + 10.0])
        for radius in (35.0, 55.0, 80.0, 110.0, 150.0, 200.0, 260.0):
            found = False
            for angle in np.radians([45, 135, 90, 0, 180, 315, 225, 270, 20, 160, 70, 110]):
                c = anchor + radius * np.array([np.cos(angle), np.sin(angle)])
                box = (c[0] - half_w, c[1] - half_h, c[0] + half_w, c[1] + half_h)
                if not (frame.x0 < box[0] and box[2] < frame.x1 and frame.y0 < box[1]
                        and box[3] < frame.y1):  # fmt: skip
                    continue
                hits = ((trace[:, 0] >= box[0]) & (trace[:, 0] <= box[2])
                        & (trace[:, 1] >= box[1]) & (trace[:, 1] <= box[3]))  # fmt: skip
                if hits.any() or any(
                    box[0] < o[2] and o[0] < box[2] and box[1] < o[3] and o[1] < box[3]
                    for o in taken
                ):
                    continue
                centre, found = c, True
                break
            if found:
                break
        taken.append((centre[0] - half_w, centre[1] - half_h, centre[0] + half_w,
                      centre[1] + half_h))  # fmt: skip
        offset = (centre - anchor) * 72.0 / fig.dpi  # display pixels -> points
        ax.annotate(
            text,
            xy=(t[i], force[i]),
            xytext=(float(offset[0]), float(offset[1])),
            textcoords="offset points",
            ha="center",
            va="center",
            fontsize=8,
            color=STAGE_COLOURS[name],
            bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "none", "alpha": 0.85},
            arrowprops={"arrowstyle": "-", "lw": 0.6, "color": STAGE_COLOURS[name]},
        )
        ax.plot(t[i], force[i], "o", ms=4, color=STAGE_COLOURS[name])


def _save(fig: Any, plt: Any, path: str | Path) -> Path:
    target = Path(path)
    if not target.parent.is_dir():
        plt.close(fig)
        raise InputError(f"cannot write {target}: folder {target.parent} does not exist")
    fig.savefig(target, dpi=110)
    plt.close(fig)
    return target


TERM_COLOURS = {
    "torque_aligning_Nm": ("#1f77b4", "aligning (tau0)"),
    "torque_tire_spin_Nm": ("#ff7f0e", "tire spin (tau1)"),
    "torque_friction_Nm": ("#2ca02c", "friction (tau2)"),
    "torque_damping_Nm": ("#9467bd", "damping (tau3)"),
    # The physical model's terms (issue 13); a run has either the paper's or these.
    "torque_jacking_Nm": ("#8c564b", "jacking"),
    "torque_park_Nm": ("#e377c2", "dry-park wind-up"),
    "torque_inertia_Nm": ("#7f7f7f", "inertia"),
    "torque_stop_Nm": ("#bcbd22", "end stop"),
    "torque_assist_Nm": ("#17becf", "assist (EPS)"),
}


def _stack_terms(ax: Any, t: np.ndarray, result: Result) -> None:
    """The physical model's terms as stacked areas: positive parts upward from 0, negative parts
    downward, so the total is the top of one stack plus the bottom of the other."""
    names = [n for n in TERM_COLOURS if n in result.names and n != "torque_tire_spin_Nm"]
    values = [np.nan_to_num(result[n]) for n in names]
    colours = [TERM_COLOURS[n][0] for n in names]
    labels = [TERM_COLOURS[n][1].split(" (tau")[0] for n in names]
    ax.stackplot(t, *[np.maximum(v, 0.0) for v in values], colors=colours, labels=labels,
                 alpha=0.7)  # fmt: skip
    ax.stackplot(t, *[np.minimum(v, 0.0) for v in values], colors=colours, alpha=0.7)


def plot_steering(
    result: Result,
    path: str | Path,
    title: str = "Steering wheel torque",
    lanes: tuple[Any, ...] = (),
) -> Path:
    """Write a PNG of a steering run, as the paper's Fig. 1-4.

    Torque and its four terms against time; torque against Ay (or against the wheel angle when
    the car stands still, Fig. 2); steering angle and Ay against time; and the car's path (with
    the cones of ISO 3888) or the terms against Ay.
    """
    plt = _pyplot()
    result = _split_segments(result)
    t = result.time_s
    torque = result["torque_Nm"]
    ay_g = result["lateral_accel_m_s2"] / 9.80665
    angle_deg = np.degrees(result["steering_angle_rad"])
    parked = bool(np.nanmax(np.abs(result["speed_m_s"])) < 1.0)

    fig, axes = plt.subplots(2, 2, figsize=(13, 8), layout="constrained")
    ax_t, ax_loop, ax_in, ax_extra = axes[0, 0], axes[0, 1], axes[1, 0], axes[1, 1]
    fig.suptitle(title)

    if "torque_assist_Nm" in result.names:
        _stack_terms(ax_t, t, result)
    else:
        for name, (colour, label) in TERM_COLOURS.items():
            if name in result.names:
                ax_t.plot(t, result[name], color=colour, lw=1.0, label=label)
    ax_t.plot(t, torque, color="k", lw=1.5, label="total")
    ax_t.set_xlabel("time [s]")
    ax_t.set_ylabel("steering wheel torque [Nm]")
    ax_t.grid(alpha=0.3)
    ax_t.legend(fontsize=8, loc="best", framealpha=0.8)  # where it hides the least of the curves
    ax_t.set_title("torque and its terms vs time")

    x_loop, x_label = (
        (angle_deg, "steering wheel angle [deg]") if parked else (ay_g, "lateral acceleration [g]")
    )
    ax_loop.plot(x_loop, torque, color="k", lw=1.2)
    ax_loop.set_xlabel(x_label)
    ax_loop.set_ylabel("steering wheel torque [Nm]")
    ax_loop.grid(alpha=0.3)
    ax_loop.set_title(
        "torque vs wheel angle (cf. paper Fig. 2)" if parked else "torque vs Ay (cf. Fig. 1, 3, 4)"
    )

    ax_in.plot(t, angle_deg, color="#d62728", lw=1.2)
    ax_in.set_xlabel("time [s]")
    ax_in.set_ylabel("steering wheel angle [deg]", color="#d62728")
    ax_in.grid(alpha=0.3)
    ax_ay = ax_in.twinx()
    ax_ay.plot(t, ay_g, color="#1f77b4", lw=1.0)
    ax_ay.set_ylabel("lateral acceleration [g]", color="#1f77b4")
    ax_in.set_title("inputs: steering angle and Ay")

    x_m, y_m = result["x_m"], result["y_m"]
    x_span = float(np.nanmax(x_m) - np.nanmin(x_m))
    y_span = float(np.nanmax(y_m) - np.nanmin(y_m))
    if x_span > 1.0 or y_span > 1.0:
        ax_extra.plot(x_m, y_m, color="k", lw=1.2, label="centre of gravity")
        for lane in lanes:
            for edge in (-0.5, 0.5):
                y_edge = lane.y_centre_m + edge * lane.width_m
                ax_extra.plot(
                    [lane.x_start_m, lane.x_end_m], [y_edge, y_edge], "o--", color="#ff7f0e",
                    ms=3, lw=0.8,
                )  # fmt: skip
        ax_extra.set_xlabel("x [m]")
        ax_extra.set_ylabel("y [m]")
        # Equal scales only where the path is not a long thin strip (it would be a squashed line).
        ax_extra.set_aspect("equal" if y_span > 0.5 * x_span else "auto")
        ax_extra.set_title("path" + (" and ISO 3888-1 cones" if lanes else ""))
    else:
        for name, (colour, label) in TERM_COLOURS.items():
            if name in result.names:  # the paper's terms, or the physical model's
                ax_extra.plot(x_loop, result[name], color=colour, lw=1.0, label=label)
        ax_extra.set_xlabel(x_label)
        ax_extra.set_ylabel("term [Nm]")
        ax_extra.legend(fontsize=8)
        ax_extra.set_title("terms vs " + ("wheel angle" if parked else "Ay"))
    ax_extra.grid(alpha=0.3)
    return _save(fig, plt, path)


def _split_segments(result: Result) -> Result:
    """A copy with a NaN row between segments, so no line joins the end of one to the next."""
    if "segment" not in result.names:
        return result
    labels = result["segment"]
    cuts = [i for i in range(1, len(labels)) if labels[i] != labels[i - 1]]
    if not cuts:
        return result
    signals = {
        name: np.insert(values.astype(float), cuts, np.nan)
        for name, values in result.signals.items()
        if values.dtype.kind == "f"
    }
    time = np.insert(result.time_s, cuts, np.nan)
    return Result(time, signals, result.metadata)


def plot_hpattern(
    result: Result,
    layout: Any,
    path: str | Path,
    title: str = "H-pattern",
    loops: EngagementLoops | None = None,
) -> Path:
    """Write a PNG of an H-pattern run: the pattern with the knob's path coloured by the force,
    and the force-position loop of each engagement along its slot (as the paper's Fig. 11).

    `result` may be the run's `Envelope` (a long run's path); `loops` its `EngagementLoops`,
    else they are taken from `result` (every sample of the run, then)."""
    plt = _pyplot()
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Rectangle

    x_mm, y_mm = result["x_m"] * 1e3, result["y_m"] * 1e3
    force = np.hypot(result["force_x_N"], result["force_y_N"])
    fig, (ax_p, ax_l) = plt.subplots(1, 2, figsize=(14, 6.5), layout="constrained")
    fig.suptitle(title)

    planes = np.asarray(layout.planes_y_m) * 1e3
    half_slot, half_corridor = layout.slot_width_m * 500, layout.corridor_width_m * 500
    reach = max(float(np.max(np.abs(x_mm))), 30.0) + 5.0
    ax_p.add_patch(
        Rectangle(
            (planes[0] - half_slot, -half_corridor), planes[-1] - planes[0] + 2 * half_slot,
            2 * half_corridor, color="#dddddd", zorder=0,
        )
    )  # fmt: skip
    for gear in layout.gears:
        y0 = planes[gear.plane] - half_slot
        x0 = 0.0 if gear.direction > 0 else -reach
        ax_p.add_patch(Rectangle((y0, x0), 2 * half_slot, reach, color="#dddddd", zorder=0))
        ax_p.annotate(
            gear.name, (planes[gear.plane], gear.direction * (reach - 2.0)), ha="center",
            va="center", fontsize=14, fontweight="bold", color="#555555",
        )  # fmt: skip
    points = np.column_stack([y_mm, x_mm]).reshape(-1, 1, 2)
    segments = np.concatenate([points[:-1], points[1:]], axis=1)
    lines = LineCollection(list(segments), cmap="viridis", linewidths=2.0, zorder=2)
    lines.set_array(force[1:])
    ax_p.add_collection(lines)
    fig.colorbar(lines, ax=ax_p, label="force on the knob [N]")
    ax_p.set_xlim(planes[0] - 3 * half_slot, planes[-1] + 3 * half_slot)
    ax_p.set_ylim(-reach, reach)
    ax_p.set_aspect("equal")
    ax_p.set_xlabel("select y [mm]")
    ax_p.set_ylabel("engage x [mm] (forward up)")
    ax_p.set_title("the pattern and the knob's path")

    if loops is None:
        loops = EngagementLoops()
        loops.write(result)
    for loop in loops.loops:
        gear = layout.gear(loop.gear)
        # Up and down shifts into the same gear told apart by where they came from.
        ax_l.plot(gear.direction * loop.x_m * 1e3, gear.direction * loop.force_x_N, lw=1.3,
                  label=loop.label)  # fmt: skip
    shown_loops = f"the first {len(loops.loops)} of {loops.count}, " if loops.more else ""
    ax_l.set_xlabel("travel along the slot [mm]")
    ax_l.set_ylabel("force along the slot [N]")
    ax_l.set_title(f"force vs position of each engagement ({shown_loops}cf. paper Fig. 11)")
    ax_l.grid(alpha=0.3)
    if loops.loops:
        ax_l.legend(fontsize=8, ncols=2)
    return _save(fig, plt, path)


@dataclass(frozen=True, slots=True)
class Loop:
    """One engagement's force along the slot against its travel, for the H-pattern plot."""

    gear: str
    label: str
    x_m: np.ndarray
    force_x_N: np.ndarray


class EngagementLoops:
    """A sink of `carfeel.simulation.stream`: the samples of the first `max_loops` engagements
    of an H-pattern run that its plot draws, at full rate: the driver's push that ends in the
    engage event and the `after` samples that follow it (the stop), those aimed at that gear.
    The run's other samples are not kept; a push longer than `max_push` samples keeps its last
    ones."""

    def __init__(
        self, max_loops: int = MAX_LOOPS, after: int = 400, max_push: int = 60_000
    ) -> None:
        self.max_loops, self.after, self.max_push = max_loops, after, max_push
        self.loops: list[Loop] = []
        self.count = 0
        self._previous = "N"
        self._push: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._tails: list[list[Any]] = []  # [loop index, samples still to take]
        self._parts: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}

    @property
    def more(self) -> bool:
        """Whether the run had engagements beyond those drawn."""
        return self.count > len(self.loops)

    def write(self, block: Result) -> None:
        x, force, targets = block["x_m"], block["force_x_N"], block["target"]
        phases, events = block["driver_phase"], block["event"]
        start = 0
        engaged = np.flatnonzero(np.char.startswith(events.astype(str), "engage")).tolist()
        for i in [*engaged, None]:
            stop = len(block) if i is None else i + 1
            piece = slice(start, stop)
            self._feed_tails(x[piece], force[piece], targets[piece])
            if (targets[piece] == "N").any():  # through neutral: 1 -> N -> 1 is "N -> 1"
                self._previous = "N"
            if len(self.loops) < self.max_loops:
                # The push that ends in this engagement: the samples since the driver last did
                # anything else (the previous push's hold at the stop is not this one's).
                other = np.flatnonzero(phases[piece] != "push")
                if other.size:
                    self._push = []
                    piece = slice(start + int(other[-1]) + 1, stop)
                self._push.append((x[piece], force[piece], targets[piece]))
                self._trim_push()
            if i is not None:
                self._engaged(str(events[i]).split()[1])
            start = stop
        self._finish()

    def _trim_push(self) -> None:
        held = sum(len(p[0]) for p in self._push)
        while held > self.max_push and self._push:
            drop = min(held - self.max_push, len(self._push[0][0]))
            first = self._push[0]
            self._push[0] = (first[0][drop:], first[1][drop:], first[2][drop:])
            if not len(self._push[0][0]):
                self._push.pop(0)
            held -= drop

    def _feed_tails(self, x: np.ndarray, force: np.ndarray, targets: np.ndarray) -> None:
        for tail in self._tails:
            index, left = tail
            taken = slice(0, min(left, len(x)))
            aimed = targets[taken] == self.loops[index].gear
            self._parts[index].append((x[taken][aimed], force[taken][aimed]))
            tail[1] = left - (taken.stop or 0)
        self._tails = [t for t in self._tails if t[1] > 0]

    def _engaged(self, gear: str) -> None:
        self.count += 1
        label = f"{self._previous} \u2192 {gear}"
        self._previous = gear
        if len(self.loops) < self.max_loops:
            index = len(self.loops)
            self.loops.append(Loop(gear, label, np.empty(0), np.empty(0)))
            self._parts[index] = [(px[pt == gear], pf[pt == gear]) for px, pf, pt in self._push]
            self._tails.append([index, self.after - 1])
        self._push = []

    def _finish(self) -> None:
        """Each loop's pieces so far put together (they are few: one per block and push)."""
        for index, parts in self._parts.items():
            loop = self.loops[index]
            self.loops[index] = Loop(
                loop.gear, loop.label,
                np.concatenate([loop.x_m, *(p[0] for p in parts)]),
                np.concatenate([loop.force_x_N, *(p[1] for p in parts)]),
            )  # fmt: skip
        self._parts = {i: [] for i, _ in self._tails}


def plot_recording(result: Result, path: str | Path, title: str = "Real-time run") -> Path:
    """Write a PNG of a real-time recording, as the paper's Fig. 10 and 11: the force estimated
    from the device (unfiltered and through the 20 Hz Butterworth low-pass) against time, and
    force against position; for a steering run, torque against time and wheel angle."""
    plt = _pyplot()
    t = result.time_s
    names = result.names
    fig, (ax_t, ax_l) = plt.subplots(1, 2, figsize=(13, 5.5), layout="constrained")
    fig.suptitle(title)
    if "torque_Nm" in names:
        raw, smooth = result["torque_Nm"], result["torque_filtered_Nm"]
        where, where_label, unit = (
            np.degrees(result["steering_angle_rad"]),
            "wheel angle [deg]",
            "Nm",
        )
        label = "steering wheel torque"
    else:
        force = "force_N" if "force_N" in names else "force_x_N"
        raw, smooth = result[force], result[f"{force[:-2]}_filtered_N"]
        position = "position_m" if "position_m" in names else "x_m"
        where, where_label, unit = result[position] * 1e3, "knob position [mm]", "N"
        label = "force on the knob, from the device"
    ax_t.plot(t, raw, color="#bbbbbb", lw=0.8, label="unfiltered")
    ax_t.plot(t, smooth, color="k", lw=1.3, label="Butterworth low-pass, 20 Hz")
    ax_t.set_xlabel("time [s]")
    ax_t.set_ylabel(f"{label} [{unit}]")
    ax_t.set_title("filtered and unfiltered (cf. paper Fig. 10)")
    ax_t.grid(alpha=0.3)
    ax_t.legend(fontsize=8)
    ax_l.plot(where, smooth, color="#1f77b4", lw=1.0)
    ax_l.set_xlabel(where_label)
    ax_l.set_ylabel(f"{label}, filtered [{unit}]")
    ax_l.set_title("force vs position loop (cf. paper Fig. 11)")
    ax_l.grid(alpha=0.3)
    return _save(fig, plt, path)


def _residual_histogram(ax: Any, residual: np.ndarray, unit: str) -> None:
    """A histogram of the residual within 4 interquartile ranges of its quartiles (about 6 sigma
    of a normal residual; a few outliers would squash the rest into one bar), saying how many
    samples fall outside the range shown."""
    finite = residual[np.isfinite(residual)]
    q1, q3 = (float(v) for v in np.percentile(finite, (25, 75)))
    low = max(q1 - 4.0 * (q3 - q1), float(finite.min()))
    high = min(q3 + 4.0 * (q3 - q1), float(finite.max()))
    if not high > low:
        low, high = low - 1e-9, high + 1e-9
    inside = (finite >= low) & (finite <= high)
    ax.hist(finite[inside], bins=80, range=(low, high), color="#1f77b4")
    ax.set_xlabel(f"model - measured [{unit}]")
    ax.set_ylabel("samples")
    outside = int(np.count_nonzero(~inside))
    rms = float(np.sqrt(np.mean(finite**2)))
    ax.set_title(
        f"rms {rms:.3g} {unit}"
        + (f"; {outside} of {len(finite)} samples beyond the range shown" if outside else ""),
        fontsize=9,
    )


MEASURED = {"color": "black", "lw": 0.7, "zorder": 3}
MODEL = {"color": "#d62728", "lw": 2.2, "alpha": 0.55, "zorder": 2}
"""The model drawn broad and translucent under the measured line: where they agree both show."""


def plot_torque_validation(
    time_s: np.ndarray,
    lateral_accel_m_s2: np.ndarray,
    measured_Nm: np.ndarray,
    model_Nm: np.ndarray,
    path: str | Path,
    title: str,
) -> Path:
    """Measured and model steering torque against time and Ay, and the residual."""
    plt = _pyplot()
    fig, (ax_t, ax_a, ax_r) = plt.subplots(1, 3, figsize=(15, 4.5), layout="constrained")
    fig.suptitle(title)
    ax_t.plot(time_s, model_Nm, label="model", **MODEL)
    ax_t.plot(time_s, measured_Nm, label="measured", **MEASURED)
    ax_t.set_xlabel("time [s]")
    ax_t.set_ylabel("steering wheel torque [Nm]")
    ax_t.legend(fontsize=8)
    ax_t.grid(alpha=0.3)
    ay_g = lateral_accel_m_s2 / 9.80665
    ax_a.plot(ay_g, model_Nm, ".", color="#d62728", ms=2.5, alpha=0.4, label="model", zorder=2)
    ax_a.plot(ay_g, measured_Nm, ".", color="black", ms=0.8, label="measured", zorder=3)
    ax_a.set_xlabel("lateral acceleration [g]")
    ax_a.set_ylabel("torque [Nm]")
    ax_a.legend(fontsize=8, markerscale=6)
    ax_a.grid(alpha=0.3)
    _residual_histogram(ax_r, model_Nm - measured_Nm, "Nm")
    return _save(fig, plt, path)


def plot_shift_validation(
    time_s: np.ndarray,
    force_N: np.ndarray,
    measured_m: np.ndarray,
    model_m: np.ndarray,
    path: str | Path,
    title: str,
) -> Path:
    """A measured engagement trace and the model driven by its force: position vs time with the
    residual (model - measured) below it, force vs position (as the paper's Fig. 5/6 and 9)."""
    plt = _pyplot()
    fig = plt.figure(figsize=(13, 6.0), layout="constrained")
    grid = fig.add_gridspec(2, 2, height_ratios=(3, 1))
    ax_t = fig.add_subplot(grid[0, 0])
    ax_r = fig.add_subplot(grid[1, 0], sharex=ax_t)
    ax_l = fig.add_subplot(grid[:, 1])
    fig.suptitle(title)
    ax_t.plot(time_s, model_m * 1e3, label="model position", **MODEL)
    ax_t.plot(time_s, measured_m * 1e3, label="measured position", **MEASURED)
    ax_t.set_ylabel("knob position [mm]")
    ax_f = ax_t.twinx()
    ax_f.plot(time_s, force_N, color="#1f77b4", lw=0.6, alpha=0.6, label="measured force")
    ax_f.set_ylabel("force at the knob [N]", color="#1f77b4")
    ax_t.set_zorder(ax_f.get_zorder() + 1)  # the positions (and the legend) over the force
    ax_t.patch.set_visible(False)
    lines = ax_t.get_legend_handles_labels()
    more = ax_f.get_legend_handles_labels()
    ax_t.legend(lines[0] + more[0], lines[1] + more[1], fontsize=8, loc="center right")
    ax_t.grid(alpha=0.3)
    ax_r.plot(time_s, (model_m - measured_m) * 1e3, color="#d62728", lw=0.8)
    ax_r.axhline(0.0, color="black", lw=0.5)
    ax_r.set_xlabel("time [s]")
    ax_r.set_ylabel("model - measured [mm]")
    ax_r.grid(alpha=0.3)
    ax_l.plot(model_m * 1e3, force_N, label="model", **MODEL)
    ax_l.plot(measured_m * 1e3, force_N, label="measured", **MEASURED)
    ax_l.set_xlabel("knob position [mm]")
    ax_l.set_ylabel("force at the knob [N]")
    ax_l.legend(fontsize=8)
    ax_l.grid(alpha=0.3)
    return _save(fig, plt, path)
