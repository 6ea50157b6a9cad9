"""The paper's figures of an evaluation (matplotlib: vector PDF and 300-dpi PNG), one
column of a two-column paper wide: accuracy per subject, accuracy and spurious switches
against delay, the switch trade-off, sequential decisions, probability traces and
confusion matrices."""

from __future__ import annotations

import math
import re
import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from devices.frames import MODE_COLORS, MODES
from inference.config import FusionConfig
from inference.evaluation.metrics import (
    TITLES,
    DelaySweep,
    by_condition,
    column_mean,
    column_sd,
    group_results,
    mean_sd,
    pooled_confusion,
    pooled_steps,
    pooled_transitions,
    run_offline,
)
from inference.evaluation.trials import Trial, TrialResult
from inference.fusion import METHOD_TABLE, N_MODES, HmmFusion

# A figure is as wide as one column of a two-column paper (3.5 in) and is printed at that
# size: every text at 6 pt or more.
COLUMN_IN = 3.5
FIGURE_STYLE = {
    "font.size": 7,
    "axes.titlesize": 7.5,
    "axes.labelsize": 7,
    "xtick.labelsize": 6.5,
    "ytick.labelsize": 6.5,
    "legend.fontsize": 6.5,
    "legend.title_fontsize": 6.5,
    "figure.titlesize": 8,
    "axes.linewidth": 0.6,
    "lines.linewidth": 1.0,
    "hatch.linewidth": 0.6,
    "pdf.fonttype": 42,  # text stays text in the PDF
}
# Methods are told apart by grey level, hatch, marker and dash, never by a mode's colour
# (colour means a mode on every screen and figure: devices.frames.MODE_COLORS).
METHOD_STYLES = {m.name: m.style for m in METHOD_TABLE}
_SPARE_STYLES = (
    {
        "color": "#909090",
        "hatch": "xxxx",
        "line": "#606060",
        "marker": "v",
        "linestyle": (0, (5, 1, 1, 1)),
    },
    {
        "color": "#d0d0d0",
        "hatch": "....",
        "line": "#909090",
        "marker": "*",
        "linestyle": (0, (1, 1)),
    },
)
FOOTNOTE_CHARS = 80  # characters a line of 6-pt text holds across one column
GAP_PERIODS = 3  # frames farther apart than this many frame periods: a gap, nothing drawn


def method_style(method: str, k: int = 0) -> dict:
    return METHOD_STYLES.get(method) or _SPARE_STYLES[k % len(_SPARE_STYLES)]


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "trial"


def write_plots(
    results: Sequence[TrialResult],
    out_dir: str | Path,
    methods: Sequence[str],
    params: FusionConfig | None = None,
    sweep: DelaySweep | None = None,
    trials: Sequence[str] | None = None,
) -> list[Path]:
    """The paper's figures in out_dir, each as a vector PDF and a 300-dpi PNG, one column
    (3.5 in) wide; returns the files written.

    accuracy_per_subject[_<condition>] (mean and SD over each subject's trials, per
    method), accuracy_vs_delay (with a sweep; mean and SD over trials, and spurious
    switches a minute below), switches (per condition, each method's accuracy against its
    spurious switches a minute, the trade-off, with its delay), steps (with gait events: per
    condition, each method's errors at heel contact against its spurious switches a
    minute), decisions_<trial> (with the heel contacts of the instrumented leg where the
    trial has steps)
    and probabilities_<trial> (every trial, or those whose file name or title contains
    one of `trials`), confusion[_<condition>] (row-normalised, with counts).
    Time is in seconds from the trial's first frame when the trial has frame times; where
    frames are missing (more than GAP_PERIODS frame periods apart) nothing is drawn.
    Modes have their colours of the live screen (devices.frames.MODE_COLORS).
    """
    import matplotlib

    params = params or FusionConfig()
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []

    def save(fig, name: str) -> None:
        for suffix, kwargs in ((".pdf", {}), (".png", {"dpi": 300})):
            path = out / f"{name}{suffix}"
            fig.savefig(path, bbox_inches="tight", pad_inches=0.02, **kwargs)
            written.append(path)
        plt.close(fig)

    with plt.rc_context(FIGURE_STYLE):
        conditions = by_condition(results)
        for condition, rs in conditions.items():
            suffix = f"_{_safe(condition)}" if condition else ""
            save(_plot_per_subject(plt, rs, methods, condition), f"accuracy_per_subject{suffix}")
        if sweep is not None:
            save(_plot_sweep(plt, results, sweep), "accuracy_vs_delay")
        save(_plot_switches(plt, results, methods, params), "switches")
        if any(r.steps for r in results):
            save(_plot_steps(plt, results, methods, params), "steps")
        for r in results:
            name = Path(r.trial.path).stem
            if trials and not any(t in name or t in r.trial.title for t in trials):
                continue
            stem = _safe(name)
            save(_plot_decisions(plt, r, methods), f"decisions_{stem}")
            save(_plot_probabilities(plt, r, params), f"probabilities_{stem}")
        for condition, rs in conditions.items():
            suffix = f"_{_safe(condition)}" if condition else ""
            save(_plot_confusion(plt, rs, methods, condition), f"confusion{suffix}")
    return written


def _sd_clipped(means: np.ndarray, sds: np.ndarray) -> np.ndarray:
    """Error bars of mean +- SD in %, cut at 0 and 100 (accuracy cannot pass them); NaN
    (no bar) where the SD is undefined (a single trial)."""
    return np.vstack([np.minimum(sds, means), np.minimum(sds, 100 - means)])


def _axis_floor(lowest: float) -> float:
    """Where an accuracy axis starts: a multiple of 5 % a little under the lowest value
    shown (bars of 95-99 % on a 0-100 % axis show no difference), 0 at the least."""
    return max(0.0, 5 * math.floor((lowest - 1.0) / 5)) if math.isfinite(lowest) else 0.0


def _legend_below(fig, ax, ncol: int, note: str = "", **kwargs) -> None:
    """The legend under the axes, never over the data (a column is too narrow for one
    beside them); `note`, what the marks mean, under the legend."""
    legend = fig.legend(
        *ax.get_legend_handles_labels(),
        loc="upper center",
        bbox_to_anchor=(0.5, 0.0),
        ncol=ncol,
        frameon=False,
        handlelength=2.2,
        columnspacing=1.0,
        **kwargs,
    )
    if note:
        _footnote(fig, note, under=legend)


def _footnote(fig, text: str, under=None) -> None:
    """A note across the column's width under the figure (or under the artist `under`,
    placed when the figure is drawn), at the smallest size a printed figure allows."""
    from matplotlib.text import Annotation

    fig.add_artist(
        Annotation(
            textwrap.fill(text, FOOTNOTE_CHARS),
            xy=(0.0, 0.0),
            xycoords=("figure fraction", under if under is not None else "figure fraction"),
            xytext=(0, -3),
            textcoords="offset points",
            ha="left",
            va="top",
            fontsize=6,
        )
    )


def _plot_per_subject(plt, results, methods, condition):
    groups = group_results(results)
    subjects = [f"{s}\n(n = {len(rs)})" for (_, s), rs in groups.items()]
    fig, ax = plt.subplots(figsize=(COLUMN_IN, 2.3), layout="constrained")
    width = 0.84 / len(methods)
    x = np.arange(len(subjects))
    lowest, labels = 100.0, []
    for k, m in enumerate(methods):
        stats = [mean_sd([r.accuracy[m] for r in rs]) for rs in groups.values()]
        means = np.array([100 * st[0] for st in stats])
        sds = np.array([100 * st[1] for st in stats])
        bars = _sd_clipped(means, sds)
        style = method_style(m, k)
        xs = x + (k - (len(methods) - 1) / 2) * width
        ax.bar(
            xs,
            means,
            width,
            yerr=bars,
            capsize=1.5,
            error_kw={"linewidth": 0.6, "capthick": 0.6},
            color=style["color"],
            hatch=style["hatch"],
            hatchcolor=style.get("hatchcolor", "black"),
            edgecolor="black",
            linewidth=0.5,
            label=TITLES.get(m, m),
        )
        low = means - np.nan_to_num(bars[0])
        if np.isfinite(low).any():
            lowest = min(lowest, float(np.nanmin(low)))
        labels += [(xi, mi, mi + np.nan_to_num(b)) for xi, mi, b in zip(xs, means, bars[1])]
    floor = _axis_floor(lowest)
    span = 100.0 - floor
    for xi, mean, top in labels:  # the value of each bar, above its error bar
        if math.isfinite(mean):
            ax.text(
                xi,
                top + 0.015 * span,
                f"{mean:.1f}",
                rotation=90,
                ha="center",
                va="bottom",
                fontsize=6,
            )
    ax.set_ylim(floor, 100.0 + 0.3 * span)  # room for the values over a 100 % bar
    ax.set_yticks([v for v in ax.get_yticks() if floor <= v <= 100])
    ax.set_xticks(x, subjects)
    ax.set_xlabel("subject (number of trials)")
    ax.set_ylabel("accuracy (%)")
    where = f", {condition}" if condition else ""
    ax.set_title(f"Accuracy per subject{where}: mean ± SD over trials")
    ax.set_ylabel(f"accuracy against {_reference_of(results)} (%)")
    _legend_below(
        fig,
        ax,
        ncol=min(4, len(methods)),
        note="Error bars: standard deviation across the subject's trials, cut at 0 and 100 %; "
        "none for a single trial.",
    )
    return fig


def _plot_sweep(plt, results, sweep):
    conditions = by_condition(results)
    index = {id(r): i for i, r in enumerate(results)}
    fig, axes = plt.subplots(
        2,
        len(conditions),
        figsize=(COLUMN_IN, 3.4),
        squeeze=False,
        sharex=True,
        sharey="row",
        height_ratios=(3, 2),
        layout="constrained",
    )
    lowest = 100.0
    for col, (condition, rs) in enumerate(conditions.items()):
        ax, low = axes[0][col], axes[1][col]
        rows = [index[id(r)] for r in rs]
        for k, (m, a) in enumerate(sweep.accuracy.items()):
            sub = a[rows]
            with np.errstate(all="ignore"):
                mean, sd = 100 * column_mean(sub), 100 * column_sd(sub)
            bars = _sd_clipped(np.nan_to_num(mean), sd)
            if np.isfinite(mean).any():
                lowest = min(lowest, float(np.nanmin(mean - np.nan_to_num(bars[0]))))
            style = method_style(m, k)
            dodge = (k - (len(sweep.accuracy) - 1) / 2) * 0.09  # methods that agree stay apart
            x = np.asarray(sweep.delays, dtype=float) + dodge
            look = dict(
                color=style["line"],
                marker=style["marker"],
                markersize=3.5,
                markeredgecolor="black",
                markeredgewidth=0.4,
                linestyle=style["linestyle"],
                label=TITLES.get(m, m),
            )
            ax.errorbar(x, mean, yerr=bars, capsize=1.5, elinewidth=0.6, **look)
            if m in sweep.spurious:
                low.plot(x, sweep.spurious_per_min(m, rows), **look)
        low.set_xticks(sweep.delays)
        low.set_xlabel("decision delay (frames)")
        n = len(rs)
        ax.set_title(f"{condition or 'all trials'} (n = {n} trial{'s' if n != 1 else ''})")
    reference = _reference_of(results)
    axes[0][0].set_ylim(_axis_floor(lowest), 100)
    axes[1][0].set_ylim(bottom=0)  # once every condition is drawn: the row shares it
    axes[0][0].set_ylabel("accuracy (%)\nmean ± SD")
    axes[1][0].set_ylabel("spurious\nswitches / min")
    fig.suptitle(f"Accuracy and spurious switches against delay ({reference} reference)")
    _legend_below(
        fig,
        axes[0][0],
        ncol=min(4, len(sweep.accuracy)),
        note="Error bars: SD across trials, cut at 100 %. Delay d: a frame's decision is made "
        f"d frames later. Spurious switches: decision changes where the {reference} "
        "reference did not change, pooled over trials.",
    )
    return fig


def _reference_of(results) -> str:
    names = sorted({r.trial.reference_name for r in results})
    return " / ".join(names) or "terrain"


def _condition_panels(plt, n: int):
    """n panels stacked, one a condition, on one x axis."""
    return plt.subplots(
        n,
        1,
        figsize=(COLUMN_IN, 0.4 + 1.6 * n),
        squeeze=False,
        sharex=True,
        layout="constrained",
    )


def _method_point(ax, m: str, k: int, params, x, y) -> None:
    """Method m's (the k-th shown) point in its style, labelled with its delay."""
    style = method_style(m, k)
    ax.plot(
        x,
        y,
        marker=style["marker"],
        color=style["line"],
        markeredgecolor="black",
        markeredgewidth=0.4,
        linestyle="none",
        markersize=4.5,
        label=f"{TITLES.get(m, m)} ({params.delay_frames(m)} fr)",
    )


def _switches_axis(axes) -> None:
    """Spurious switches a minute along x: a point at 0 shows whole, on one scale for
    every condition."""
    for (ax,) in axes:
        right = max(1.0, ax.get_xlim()[1])
        ax.set_xlim(-0.04 * right, right)
    axes[-1][0].set_xlabel("spurious switches a minute")


def _plot_switches(plt, results, methods, params):
    """Per condition (one panel each, stacked): each method's accuracy (mean over trials)
    against its spurious switches a minute (pooled), with its delay: the trade-off a
    controller feels."""
    conditions = by_condition(results)
    fig, axes = _condition_panels(plt, len(conditions))
    reference = _reference_of(results)
    for (ax,), (condition, rs) in zip(axes, conditions.items()):
        for k, m in enumerate(methods):
            stats = pooled_transitions(rs, m).get(reference)
            if stats is None:
                continue
            _method_point(
                ax,
                m,
                k,
                params,
                stats.spurious_per_min,
                100 * mean_sd([r.accuracy[m] for r in rs])[0],
            )
        ax.set_ylabel("accuracy (%)")
        ax.grid(True, linewidth=0.3)
        n = len(rs)
        ax.set_title(f"{condition or 'all trials'} (n = {n} trial{'s' if n != 1 else ''})")
    _switches_axis(axes)
    fig.suptitle(f"Accuracy against spurious switches ({reference} reference)")
    _legend_below(
        fig,
        axes[0][0],
        ncol=2,
        title="method (delay in frames); up and left is better",
        note="Accuracy: mean over trials. Spurious switches: decision changes with no change "
        "of the reference to that mode within 2 s, pooled over trials.",
    )
    return fig


def _plot_steps(plt, results, methods, params):
    """Per condition (one panel each, stacked): each method's errors at heel contact
    (pooled over the trials' steps) against its spurious switches a minute: what a
    prosthesis acting at steps feels."""
    conditions = {c: rs for c, rs in by_condition(results).items() if any(r.steps for r in rs)}
    fig, axes = _condition_panels(plt, len(conditions))
    reference = _reference_of(results)
    for (ax,), (condition, rs) in zip(axes, conditions.items()):
        for k, m in enumerate(methods):
            steps = pooled_steps(rs, m)
            switches = pooled_transitions(rs, m).get(reference)
            if steps is None or switches is None:
                continue
            _method_point(
                ax, m, k, params, switches.spurious_per_min, 100 * steps.error_rate_at_heel_contact
            )
        ax.set_ylabel("errors at heel contact (%)")
        ax.grid(True, linewidth=0.3)
        heel = sum(r.steps[methods[0]].heel_contacts for r in rs if methods[0] in r.steps)
        ax.set_title(f"{condition or 'all trials'} ({heel} heel contacts)")
        ax.set_ylim(bottom=0)
    _switches_axis(axes)
    fig.suptitle("Errors at heel contact against spurious switches")
    _legend_below(
        fig,
        axes[0][0],
        ncol=2,
        title="method (delay in frames); down and left is better",
        note="Errors at heel contact: the decision in force at each heel contact of the "
        "instrumented leg against that step's mode, pooled over trials. Spurious switches: "
        f"against the {reference} reference, as in the switches figure.",
    )
    return fig


def _time_axis(trial: Trial) -> tuple[np.ndarray, str]:
    if trial.times_s is not None and len(trial.times_s) == len(trial.reference):
        return trial.times_s, "time (s)"
    return np.arange(len(trial.reference), dtype=float), "frame"


def _frame_period(t: np.ndarray) -> float:
    steps = np.diff(t)
    steps = steps[steps > 0]
    return float(np.median(steps)) if len(steps) else 1.0


def gap_breaks(t: np.ndarray) -> np.ndarray:
    """Indices i where frames i and i+1 are a gap apart (missing frames, a stall)."""
    if len(t) < 2:
        return np.zeros(0, dtype=int)
    return np.flatnonzero(np.diff(t) > GAP_PERIODS * _frame_period(t))


def _runs(t: np.ndarray, values: np.ndarray):
    """(start, end, value) of each run of equal values that no gap interrupts; a frame
    spans one frame period from its time; -1 (none) is no run."""
    period = _frame_period(t)
    cut = np.zeros(len(t), dtype=bool)
    cut[gap_breaks(t) + 1] = True
    start = 0
    for i in range(1, len(t) + 1):
        if i == len(t) or cut[i] or values[i] != values[start]:
            if values[start] >= 0:
                yield t[start], t[i - 1] + period, int(values[start])
            start = i


def _with_gaps(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """t and values with a NaN row inserted in every gap, so that lines break there."""
    breaks = gap_breaks(t)
    if not len(breaks):
        return t, values
    t2 = np.insert(t.astype(float), breaks + 1, np.nan)
    v2 = np.insert(values.astype(float), breaks + 1, np.nan, axis=0)
    return t2, v2


def _mode_legend(fig, none: str = "") -> None:
    """The modes' colours with their letters, under the figure; `none`: what white means."""
    from matplotlib.patches import Patch

    handles = [Patch(facecolor=MODE_COLORS[m], label=m) for m in MODES]
    if none:
        handles.append(Patch(facecolor="white", edgecolor="#888888", linewidth=0.5, label=none))
    fig.legend(
        handles=handles,
        loc="upper center",
        bbox_to_anchor=(0.5, 0.0),
        ncol=len(handles),
        frameon=False,
        handlelength=1.2,
        columnspacing=0.9,
    )


def _plot_decisions(plt, result, methods):
    """The paper's Fig. 8 as the live screen draws it: one strip per source (reference,
    then each method), coloured by mode; white where there is no frame or no decision."""
    trial = result.trial
    t, xlabel = _time_axis(trial)
    rows = [(f"{trial.reference_name}\n(reference)", trial.reference)]
    if trial.locomotion is not None and trial.reference_name != "locomotion":
        rows.append(("locomotion\n(keyed live)", trial.locomotion))
    rows += [
        (f"{TITLES.get(m, m)}\n{100 * result.accuracy[m]:.1f} %", result.runs[m].final)
        for m in methods
    ]
    fig, ax = plt.subplots(figsize=(COLUMN_IN, 0.35 * len(rows) + 0.9), layout="constrained")
    for k, (_, values) in enumerate(rows):
        y = len(rows) - 1 - k
        by_mode: dict[int, list] = {}
        for start, end, mode in _runs(t, np.asarray(values)):
            by_mode.setdefault(mode, []).append((start, end - start))
        for mode, spans in by_mode.items():  # one shape per mode and strip: quick to draw
            ax.broken_barh(
                spans, (y - 0.38, 0.76), facecolors=MODE_COLORS[MODES[mode]], linewidth=0
            )
    ax.set_yticks(range(len(rows)), [name for name, _ in reversed(rows)])
    ax.set_ylim(-0.6, len(rows) - 0.4)
    steps = getattr(trial, "steps", None)
    if steps is not None and len(steps.heel_contacts_s) and xlabel == "time (s)":
        # where a prosthesis reads the mode
        ax.vlines(steps.heel_contacts_s, -0.6, len(rows) - 0.4, colors="black", linewidth=0.3)
        xlabel += "; lines: heel contacts of the instrumented leg"
    ax.set_xlabel(xlabel)
    ax.set_xlim(t[0] if len(t) else 0, (t[-1] + _frame_period(t)) if len(t) else 1)
    ax.tick_params(axis="y", length=0)
    for side in ("left", "right", "top"):
        ax.spines[side].set_visible(False)
    ax.set_title(f"Sequential decisions: {trial.title}\n(accuracy against {trial.reference_name})")
    _mode_legend(fig, none="none")
    return fig


def _plot_probabilities(plt, result, params):
    trial = result.trial
    t, xlabel = _time_axis(trial)
    hmms = [m.name for m in METHOD_TABLE if m.cls is HmmFusion]  # alone first, then voted
    run = next((result.runs[m] for m in hmms if m in result.runs), None)
    if run is None:
        run = run_offline(params.make(hmms[0]), trial.probabilities)
    fig, axes = plt.subplots(2, 1, figsize=(COLUMN_IN, 2.9), sharex=True, layout="constrained")
    for ax, p, title in (
        (axes[0], trial.probabilities, "CNN softmax output"),
        (axes[1], run.posteriors, f"HMM smoothed posterior (window {params.window} frames)"),
    ):
        tt, pp = _with_gaps(t, np.asarray(p, dtype=float))
        for j, mode in enumerate(MODES):
            ax.plot(tt, pp[:, j], label=mode, linewidth=0.8, color=MODE_COLORS[mode])
        ax.set_ylim(0, 1.02)
        ax.set_ylabel("probability")
        ax.set_title(title)
    axes[1].set_xlabel(xlabel)
    axes[1].set_xlim(t[0] if len(t) else 0, t[-1] if len(t) else 1)
    fig.suptitle(f"Probability traces: {trial.title}")
    _mode_legend(fig)
    return fig


def _plot_confusion(plt, results, methods, condition=""):
    cols = 2 if len(methods) > 1 else 1
    grid = math.ceil(len(methods) / cols)
    fig, axes = plt.subplots(
        grid,
        cols,
        figsize=(COLUMN_IN, 1.5 * grid + 0.45),
        squeeze=False,
        layout="constrained",
    )
    image = None
    for ax in axes.flat[len(methods) :]:
        ax.set_visible(False)
    for ax, m in zip(axes.flat, methods):
        counts = pooled_confusion(results, m)
        with np.errstate(all="ignore"):
            rate = 100 * counts / counts.sum(axis=1, keepdims=True)
        image = ax.imshow(np.nan_to_num(rate), vmin=0, vmax=100, cmap="Greys")
        for i in range(N_MODES):
            for j in range(N_MODES):
                if counts[i].sum() == 0:
                    continue
                ax.text(
                    j,
                    i,
                    f"{rate[i, j]:.0f}",
                    ha="center",
                    va="center",
                    fontsize=6.5,
                    color="white" if rate[i, j] > 55 else "black",
                )
        rows = [f"{mode} {counts[i].sum()}" for i, mode in enumerate(MODES)]
        ax.set_xticks(range(N_MODES), MODES)
        ax.set_yticks(range(N_MODES), rows)
        ax.tick_params(length=0, pad=1.5)
        ax.set_xlabel("decided", labelpad=1)
        ax.set_title(TITLES.get(m, m))
    for row in axes:
        row[0].set_ylabel("reference, frames", labelpad=1)
    bar = fig.colorbar(image, ax=axes, fraction=0.04, pad=0.02, shrink=0.8)
    bar.set_label("% of the reference row")
    n = len(results)
    where = condition or "all trials"
    fig.suptitle(
        f"Confusion, {where} (n = {n} trial{'s' if n != 1 else ''}),\n"
        f"against the {_reference_of(results)} reference: row %"
    )
    return fig
