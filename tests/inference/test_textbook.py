"""The textbook set: the authors' recipe, drawn and rasterised; the bundled model reads it."""

import numpy as np
import pytest

from devices.frames import MODES
from inference.textbook import PER_CLASS, textbook_set


def _risers(image: np.ndarray) -> int:
    """Columns holding a vertical run of at least 8 occupied cells (a riser of >= 8 cm)."""
    return int((image.sum(axis=0) >= 8).sum())


def test_textbook_set_follows_the_recipe():
    images, labels = textbook_set(per_class=20, seed=5)
    assert images.shape == (100, 100, 100) and images.dtype == np.uint8
    assert np.bincount(labels).tolist() == [20] * 5
    again, _ = textbook_set(per_class=20, seed=5)
    np.testing.assert_array_equal(images, again)  # a pure function of its seed
    for image, label in zip(images, labels):
        mode = MODES[label]
        rows, cols = np.nonzero(image)
        assert rows.max() == 98  # the authors' shift: the lowest point in row 98
        assert cols.min() == 1 and cols.max() == 99  # 0.99 m of terrain
        near, far = rows[cols < 10].mean(), rows[cols > 90].mean()
        if mode == "LG":  # a plane with +-1 cm noise: a band of at most 3 rows
            assert rows.min() >= 96
        elif mode in ("US", "UR"):  # rows count downwards: up is a smaller row
            assert far < near - 15
        else:
            assert far > near + 15
        if mode in ("US", "DS"):  # risers drawn, up or down, 0.10-0.20 m high
            assert _risers(image) >= 2
        else:
            assert _risers(image) == 0


@pytest.mark.parametrize("mode", MODES)
def test_the_bundled_model_reads_the_textbook_set(mode, textbook_predictions):
    images, labels, predictions = textbook_predictions
    assert len(images) == 5 * PER_CLASS
    label = MODES.index(mode)
    right = float(np.mean(predictions[labels == label] == label))
    assert right >= 0.98, f"{mode}: {right:.0%} of the textbook images"


@pytest.fixture(scope="module")
def textbook_predictions():
    from inference.model import load_classifier

    images, labels = textbook_set()
    predictions = np.argmax(load_classifier(None).predict_batch(images, batch_size=100), axis=1)
    return images, labels, predictions


def test_eval_model_scores_the_textbook_set(capsys):
    import json

    from tui import cli

    assert cli.main(["eval", "model", "--textbook", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    metrics = report["metrics"]
    assert metrics["frames"] == 5 * PER_CLASS
    assert set(metrics["per_class"]) == set(MODES)
