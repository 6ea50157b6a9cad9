import pytest

from capture.errors import CaptureError
from capture.live.labels import LabelBook


def test_an_undo_brings_the_mode_before_back():
    book = LabelBook()
    assert book.undo(5) is None and book.label is None
    book.change("LG", "operator", 10)
    book.change("US", "operator", 20)
    change, undone = book.undo(30)
    assert (change.time_ns, change.mode, change.source) == (30, "LG", "undo")
    assert undone.mode == "US" and book.label == "LG"
    change, _ = book.undo(40)
    assert change.mode == "" and book.label is None  # nothing in force any more


def test_an_unknown_mode_is_refused_and_changes_nothing():
    book = LabelBook()
    book.change("DR", "simulator", 1)
    with pytest.raises(CaptureError, match="unknown mode 'XX'"):
        book.change("XX", "operator", 2)
    assert book.label == "DR"
