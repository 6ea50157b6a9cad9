"""The UI's pure parts: rasters, strips, bars, big letters, the form and its memory."""

import json

import numpy as np
import pytest

from capture.config import Config
from capture.errors import CaptureError
from capture.live.timeline import TimelineEntry
from capture.live.trials import SubjectInfo
from tests.tui.screens import FILLED_SUBJECT
from tui.app import keymap
from tui.session_screen import (
    form_values,
    info_from_form,
    last_session_path,
    load_last_session,
    save_last_session,
)
from tui.widgets.decision import big_letters
from tui.widgets.features import feature_rows
from tui.widgets.help_screen import key_label
from tui.widgets.modes import MODE_COLORS, mode_color, mode_name
from tui.widgets.probability_bars import bar
from tui.widgets.profile_plot import profile_ranges
from tui.widgets.raster import (
    braille_lines,
    fit_binary_image,
    halfblock_lines,
    plot_points,
    pool_any,
)
from tui.widgets.recording_panel import clock_text, human_bytes
from tui.widgets.timeline import strip_cells, strip_text


def test_halfblocks_pair_rows():
    img = np.array([[1, 0, 1, 0], [0, 1, 1, 0]])
    assert halfblock_lines(img) == ["▀▄█ "]
    assert halfblock_lines(np.array([[1]])) == ["▀"]  # an odd row count pads with empty


def test_braille_sets_the_right_dots():
    img = np.zeros((4, 2), dtype=np.uint8)
    img[0, 0] = 1  # dot 1
    img[3, 1] = 1  # dot 8
    assert braille_lines(img) == [chr(0x2800 + 0x01 + 0x80)]
    assert braille_lines(np.ones((4, 4))) == ["⣿⣿"]


def test_pool_any_keeps_thin_lines():
    img = np.zeros((100, 100), dtype=np.uint8)
    img[37, :] = 1  # a one-pixel tread
    pooled = pool_any(img, 3)
    assert pooled.shape == (34, 34)
    assert pooled[12].all() and pooled.sum() == 34


def test_fit_picks_the_densest_rendering_that_fits():
    img = np.eye(100, dtype=np.uint8)
    lines, factor, style = fit_binary_image(img, 100, 50)  # room for half-blocks at full size
    assert (factor, style, len(lines), len(lines[0])) == (1, "half", 50, 100)
    lines, factor, style = fit_binary_image(img, 50, 25)  # braille at full size
    assert (factor, style, len(lines), len(lines[0])) == (1, "braille", 25, 50)
    lines, factor, style = fit_binary_image(img, 26, 28)
    assert style == "braille" and factor == 2 and len(lines[0]) <= 26 and len(lines) <= 28
    assert fit_binary_image(img, 0, 10) == ([], 0, "")


def test_profile_plot_puts_points_where_they_belong():
    pts = np.array([[0.0, 0.0], [1.0, 1.0]])
    lines = plot_points(pts, 1, 1, (0.0, 2.0), (0.0, 2.0))  # 2 x 4 dots over 2 m x 2 m
    # (0, 0) lands bottom-left (dot 7), (1, 1) top-right of the lower half (dot 6)
    assert lines == [chr(0x2800 + 0x40 + 0x20)]
    assert plot_points(np.array([[np.nan, 0.0], [5.0, 5.0]]), 2, 2, (0, 1), (0, 1)) == ["⠀⠀", "⠀⠀"]


def test_profile_ranges_have_equal_scales_and_keep_the_profile_in_view():
    pts = np.array([[0.1, -0.2], [1.2, 0.4]])
    (x0, x1), (y0, y1) = profile_ranges(pts, 40, 20)
    assert (x1 - x0) / 80 == pytest.approx((y1 - y0) / 80)
    assert y0 <= -0.2 and y1 >= 0.4


def test_strip_cells_bins_the_last_span():
    now = 20_000_000_000
    entries = [
        TimelineEntry(i, now - (19 - i) * 1_000_000_000, "LG" if i < 10 else "US", i % 5)
        for i in range(20)
    ]
    cells = strip_cells(entries, "label", now, 20)
    assert cells[1:11] == ["LG"] * 10 and cells[11:] == ["US"] * 9
    assert cells[0] == ""  # exactly 20 s ago falls off the left edge: before the first frame
    assert strip_cells(entries, "cnn", now, 20)[5] == "DR"  # entry 4 (cnn 4) falls in column 5
    old = [TimelineEntry(0, now - 30_000_000_000, "DR", 4)]
    assert strip_cells(old, "label", now, 10) == [None] * 10  # frames before: all gaps
    assert strip_cells([], "label", now, 3) == ["", "", ""]
    gap = [entries[0], entries[5]]
    assert strip_cells(gap, "label", now, 20)[:7] == ["", "LG", None, None, None, None, "LG"]


def test_strip_text_letters_each_run():
    text = strip_text([""] + ["LG"] * 5 + [None] * 2 + ["US"] * 2)
    assert text.plain == " LG   ··  "
    assert MODE_COLORS["LG"] in str(text.spans[0].style) and text.spans[0].start == 1


def test_bars_and_letters():
    assert bar(0.5, 10) == "█████     "
    assert bar(1.0, 4) == "████" and bar(0.0, 3) == "   " and bar(float("nan"), 2) == "  "
    assert bar(0.0625, 2) == "▏ "
    rows = big_letters("US")
    assert len(rows) == 5 and all(len(r) == 22 for r in rows)
    assert mode_name(2) == "DS" and mode_name("UR") == "UR" and mode_name(None) is None
    assert mode_color("XX") != mode_color("LG")


def test_feature_rows_format_known_and_unknown():
    rows = feature_rows({"slope_deg": 12.34, "riser_m": 0.1612, "width": 0.5, "none": None})
    assert rows == [("slope", "+12.3°"), ("riser", "0.161 m"), ("width", "0.5")]
    rows = feature_rows({"kind": "stairs", "direction": "down", "steps": 2, "inlier_fraction": 0.9})
    assert rows == [("", "fits stairs down, 2 steps"), ("fit", "90%")]


def test_small_formatters():
    assert human_bytes(999) == "999 B" and human_bytes(12_345_678) == "12.3 MB"
    assert clock_text(3725.9) == "1:02:05"
    assert (
        key_label("question_mark") == "?"
        and key_label("space") == "space"
        and key_label("1") == "1"
    )


def test_keymap_follows_config_keys():
    config = Config()
    config.keys.mode_lg = "a"
    km = keymap(config)
    assert km["walkcap.mode_lg"] == "a" and km["walkcap.freeze"] == "space"


def test_form_round_trip_and_validation():
    info = FILLED_SUBJECT
    assert info_from_form(form_values(info)) == info
    values = form_values(info)
    with pytest.raises(CaptureError, match="height"):
        info_from_form({**values, "height_m": "tall"})
    with pytest.raises(CaptureError, match="side"):
        info_from_form({**values, "side": ""})
    with pytest.raises(CaptureError, match="subject"):
        info_from_form({**values, "subject": ""})
    with pytest.raises(CaptureError, match="trial"):
        info_from_form({**values, "trial": ""})


def test_last_session_is_remembered_under_home(tmp_path):
    assert load_last_session() == SubjectInfo()  # nothing saved yet
    info = SubjectInfo(subject="S07", condition="outdoor", trial=4)
    save_last_session(info)
    path = last_session_path()
    assert path == tmp_path / ".config" / "walkcap" / "last_session.json"
    assert json.loads(path.read_text())["subject"] == "S07"
    assert load_last_session() == info
    path.write_text("{not json")
    assert load_last_session() == SubjectInfo()  # a broken file never blocks the session
    path.write_text(json.dumps({"subject": "bad name!", "trial": 2}))
    assert load_last_session() == SubjectInfo()


def test_write_rate_and_recording_rows():
    from capture.recording.writer import RecorderState, RecorderStats
    from tui.widgets.recording_panel import ByteRate, recording_rows

    rate = ByteRate(window_s=2.0)
    assert rate.add(0, 0) is None
    assert rate.add(1_000_000_000, 500_000) == pytest.approx(500_000)
    assert rate.add(4_000_000_000, 3_500_000) == pytest.approx(
        1_000_000
    )  # the old reading aged out
    assert rate.add(5_000_000_000, 100) is None  # a new file starts over
    stats = RecorderStats(
        path="/r/S01_indoor_t01.mcap",
        state=RecorderState.FAILED,
        message="disk full",
        bytes_written=2_000_000,
        queue_depth=1500,
        queue_size=2048,
        dropped=7,
    )
    rows = {
        label: (value, style) for label, value, style in recording_rows(stats, 61.0, None, "", 1e6)
    }
    assert rows["● REC"][0] == "0:01:01" and rows["FAILED"][0] == "disk full"
    assert rows["file"][0] == "S01_indoor_\nt01.mcap" and rows["write"][0] == "1.0 MB/s"
    assert rows["queue"] == ("73 % full", "bold #f0a020") and rows["dropped"][0] == "7 messages"
    gaps = recording_rows(stats, 61.0, None, "", 1e6, gaps={"camera": 2, "imu": 35})
    assert ("gaps", "camera 2, IMU 35", "bold #f0a020") in gaps
    assert recording_rows(None, None, None, "r: record trial 3")[1][0] == "r: record trial 3"


def test_device_rows_show_state_rates_errors_clock():
    from devices.base import DeviceState, DeviceStatus
    from tui.widgets.device_panel import device_rows

    imu = DeviceStatus(
        "serial",
        DeviceState.DEGRADED,
        "3 packets missing",
        100.0,
        80.0,
        dropped=1,
        errors=5,
        details={"offset_ms": -2.5, "drift_ppm": 51.0, "checksum_errors": 2, "missing_packets": 3},
    )
    rows = {
        label: value for label, value, _ in device_rows("imu", imu, {"p50_ms": 0.5, "p99_ms": 2.0})
    }
    lines = device_rows("imu", imu, {"p50_ms": 0.5, "p99_ms": 2.0})
    assert lines[0][:2] == ("IMU", "degraded  serial") and lines[1][1] == "3 packets missing"
    assert rows["rate"] == "80.0 of 100 Hz" and rows["drops"] == "1 samples, errors 5"
    assert ("", "bad checksums: 2") in [r[:2] for r in lines]
    assert ("", "missing packets: 3") in [r[:2] for r in lines]
    # drift and sync error, never the raw device-to-host clock offset
    assert rows["drift"] == "+51 ppm (clock)" and rows["sync"] == "error p99 2.0 ms"
    assert not any("-2.5" in value for _, value, _ in lines)
    assert device_rows("camera", None) == [("camera", "not open", "dim")]


def test_decision_panel_adds_switches_and_the_walkers_mode():
    from rich.console import Console

    from tui.widgets.decision import DecisionDisplay

    def text(widget) -> str:
        console = Console(width=60, record=True)
        console.print(widget.render())
        return " ".join(console.export_text().split())  # as read, however it wraps

    panel = DecisionDisplay()
    panel.present("US", "US", "LG")
    assert "switches" not in text(panel) and "walker" not in text(panel)
    panel.present_switching(3, "US")
    out = text(panel)
    assert "switches/min 3" in out and "walker US" in out


def test_the_image_caption_fits_a_narrow_panel_with_a_long_flag():
    """At 80x24 the image panel is 18 cells wide: a stale_orientation flag (17 characters)
    leaves no room for any caption, and the panel still draws: during the unplug drill
    a drawing fault would end the live screen mid-trial."""
    from tui.widgets.binary_image import BinaryImage

    widget = BinaryImage()
    widget.present(np.zeros((100, 100), dtype=bool), "stale_orientation")
    for width in (18, 12, 8):
        lines = widget.build_lines(width, 10)
        text = "".join(t for t, _ in lines[-1])
        assert len(text) <= width and "stale" in text
