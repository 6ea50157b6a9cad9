"""`eval recordings --plot` figures say no more than the data: lines and strips break at
gaps, modes have the live screen's colours, the four methods are told apart, every figure
reads at one column's width (3.5 in), per-subject bars have a useful axis and values."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.colors import to_hex  # noqa: E402
from matplotlib.container import BarContainer  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.text import Text  # noqa: E402

import inference.evaluation as ev  # noqa: E402
from devices.frames import MODE_COLORS, MODES  # noqa: E402
from tests.scored_trials import synthetic_trial  # noqa: E402
from tui.widgets import modes as tui_modes  # noqa: E402

FPS = 15.0
METHODS = list(ev.PAPER_METHODS)


def trial_with_gap(seed: int, subject: str = "S01", condition: str = "indoor", trial: int = 1):
    """A trial at 15 fps whose middle 2 s never arrived (a stall, an unplugged IMU)."""
    t = synthetic_trial(
        seed=seed,
        accuracy=0.96,
        metadata={"subject": subject, "condition": condition, "trial": trial},
        path=f"{subject}_{condition}_t{trial:02d}.mcap",
    )
    n = len(t.reference)
    keep = np.ones(n, bool)
    keep[n // 2 : n // 2 + 30] = False
    times = (np.arange(n) / FPS)[keep]
    return ev.Trial(t.path, t.probabilities[keep], t.reference[keep], t.metadata, times)


@pytest.fixture(scope="module")
def results():
    trials = [
        trial_with_gap(k + 1, subject, condition, trial)
        for k, (subject, condition, trial) in enumerate(
            (s, c, n) for c in ("indoor", "outdoor") for s in ("S01", "S02") for n in (1, 2)
        )
    ]
    return ev.evaluate(trials, METHODS), ev.delay_sweep(trials, METHODS, 2)


@pytest.fixture
def figures(monkeypatch):
    """Every figure write_plots would save, kept open for inspection (not written: the
    files are test_evaluation's)."""
    saved = {}
    close = plt.close

    def keep(fig, path, *args, **kwargs):
        saved[str(path).rsplit("/", 1)[-1].rsplit(".", 1)[0]] = fig

    monkeypatch.setattr(Figure, "savefig", keep)
    monkeypatch.setattr(plt, "close", lambda fig=None: None)
    yield saved
    for fig in saved.values():
        close(fig)


def gap_of(trial) -> tuple[float, float]:
    steps = np.diff(trial.times_s)
    i = int(np.argmax(steps))
    return float(trial.times_s[i]), float(trial.times_s[i + 1])


def spans(ax):
    """(x0, x1) of every filled shape (strips, bars) in the axes."""
    out = []
    for collection in ax.collections:
        for path in collection.get_paths():
            xs = path.vertices[:, 0]
            out.append((float(xs.min()), float(xs.max())))
    return out


def test_lines_and_strips_break_at_a_gap(results, figures, tmp_path):
    rs, _ = results
    ev.write_plots(rs[:1], tmp_path, METHODS, trials=["S01_indoor_t01"])
    start, end = gap_of(rs[0].trial)
    middle = (start + end) / 2
    probabilities = figures["probabilities_S01_indoor_t01"]
    lines = [
        line for ax in probabilities.axes for line in ax.get_lines() if line.get_label()[0] != "_"
    ]
    assert len(lines) == 2 * len(MODES)
    for line in lines:
        x, y = np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)
        drawn = np.isfinite(x) & np.isfinite(y)
        joined = drawn[:-1] & drawn[1:]  # segments that are drawn
        assert not np.any(joined & (x[:-1] < middle) & (x[1:] > middle)), line.get_label()
    decisions = figures["decisions_S01_indoor_t01"]
    (ax,) = [a for a in decisions.axes if a.get_visible()]
    for x0, x1 in spans(ax):
        assert not (x0 < middle < x1), "a strip runs across the gap"
        for line in ax.get_lines():  # and no step line crosses it either
            x = np.asarray(line.get_xdata(), float)
            assert not np.any((x[:-1] < middle) & (x[1:] > middle))


def test_modes_have_the_live_screens_colours(results, figures, tmp_path):
    assert tui_modes.MODE_COLORS is MODE_COLORS  # one table for the UI and the figures
    rs, _ = results
    ev.write_plots(rs[:1], tmp_path, METHODS, trials=["S01_indoor_t01"])
    for ax in figures["probabilities_S01_indoor_t01"].axes:
        for line in ax.get_lines():
            if line.get_label() in MODES:
                assert to_hex(line.get_color()) == MODE_COLORS[line.get_label()]
    (ax,) = figures["decisions_S01_indoor_t01"].axes
    fills = {to_hex(c) for coll in ax.collections for c in coll.get_facecolors()}
    assert fills and fills <= set(MODE_COLORS.values())


def test_the_four_methods_are_told_apart(results, figures, tmp_path):
    rs, sweep = results
    ev.write_plots(rs, tmp_path, METHODS, sweep=sweep, trials=["S01_indoor_t01"])
    (bars_ax,) = figures["accuracy_per_subject_indoor"].axes
    looks = {}
    for container in bars_ax.containers:
        if not isinstance(container, BarContainer):
            continue
        bar = container.patches[0]
        looks[container.get_label()] = (to_hex(bar.get_facecolor()), bar.get_hatch() or "")
    assert len(looks) == 4 and len(set(looks.values())) == 4
    assert not {face for face, _ in looks.values()} & set(MODE_COLORS.values())
    sweep_ax = figures["accuracy_vs_delay"].axes[0]
    lines = [line for line in sweep_ax.get_lines() if line.get_marker() not in ("", "None", "_")]
    styles = {(line.get_marker(), str(line.get_linestyle())) for line in lines}
    assert len(styles) == 4
    xs = [tuple(np.round(line.get_xdata(), 3)) for line in lines]
    assert len(set(xs)) == 4  # methods that agree are not drawn on top of each other
    (ax,) = figures["decisions_S01_indoor_t01"].axes
    rows = [t.get_text() for t in ax.get_yticklabels()]
    for m in METHODS:
        assert sum(ev.TITLES[m] + "\n" in r for r in rows) == 1  # a strip of its own


def test_every_figure_reads_at_one_columns_width(results, figures, tmp_path):
    rs, sweep = results
    ev.write_plots(rs, tmp_path, METHODS, sweep=sweep, trials=["S01_indoor_t01"])
    assert len(figures) == 8 and "switches" in figures  # main's trade-off figure too
    for name, fig in figures.items():
        width, _ = fig.get_size_inches()
        assert width <= 3.5 + 1e-9, name
        fig.canvas.draw()
        sizes = [
            t.get_fontsize() for t in fig.findobj(Text) if t.get_visible() and t.get_text().strip()
        ]
        assert min(sizes) >= 6, (name, min(sizes))


def test_per_subject_bars_have_a_useful_axis_and_their_values(results, figures, tmp_path):
    rs, _ = results
    ev.write_plots(rs, tmp_path, METHODS, trials=["none"])
    (ax,) = figures["accuracy_per_subject_indoor"].axes
    low, high = ax.get_ylim()
    heights = [p.get_height() for c in ax.containers if isinstance(c, BarContainer) for p in c]
    assert min(heights) > 90 and low >= 80 and high >= 100  # not 0-100 % for 95-99 % values
    texts = {t.get_text() for t in ax.texts}
    assert {f"{h:.1f}" for h in heights} <= texts
