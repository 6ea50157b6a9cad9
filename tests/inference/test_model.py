"""The terrain CNN: architecture, initialisation, inference paths, safe files, errors."""

import json

import numpy as np
import pytest
import torch

from devices.frames import MODES
from inference.errors import InferenceError
from inference.model import (
    BUNDLED_PATH,
    BUSY,
    Classifier,
    TerrainCNN,
    load_classifier,
    metadata_path,
    save_model,
)


def _images(n: int, seed: int = 0) -> np.ndarray:
    return (np.random.default_rng(seed).random((n, 100, 100)) < 0.05).astype(np.uint8)


def _trained_looking(hidden: int = 8, seed: int = 0) -> TerrainCNN:
    """A network with non-trivial batch-norm statistics, as after training."""
    torch.manual_seed(seed)
    net = TerrainCNN(hidden=hidden)
    for bn in (net.bn1, net.bn2, net.bn3):
        bn.running_mean.uniform_(-0.1, 0.1)
        bn.running_var.uniform_(0.5, 2.0)
        bn.weight.data.uniform_(0.5, 1.5)
        bn.bias.data.uniform_(-0.2, 0.2)
    for m in net.modules():  # larger weights so that the scores differ between images
        if isinstance(m, (torch.nn.Conv2d, torch.nn.Linear)):
            m.weight.data *= 20
    return net.eval()


def test_architecture_is_the_papers():
    net = TerrainCNN(hidden=32)
    convs = [net.conv1, net.conv2, net.conv3]
    assert [c.out_channels for c in convs] == [16, 32, 64]
    assert all(c.kernel_size == (3, 3) for c in convs)
    assert [b.num_features for b in (net.bn1, net.bn2, net.bn3)] == [16, 32, 64]
    assert net.fc1.in_features == 64 * 25 * 25  # two 2 x 2 pools: 100 -> 50 -> 25
    assert net.fc2.out_features == len(MODES) == 5
    assert net(torch.zeros(3, 1, 100, 100)).shape == (3, 5)
    n_params = sum(p.numel() for p in net.parameters())
    assert n_params * 4 < 8e6  # the bundled file must stay under 8 MB


def test_initialisation_is_normal_0_001():
    torch.manual_seed(0)
    net = TerrainCNN(hidden=32)
    w = torch.cat([net.conv3.weight.flatten(), net.fc1.weight.flatten()[:100_000]]).detach()
    assert abs(float(w.mean())) < 1e-3 and float(w.std()) == pytest.approx(0.01, rel=0.05)
    assert float(net.conv1.weight.detach().std()) < 0.03
    for m in (net.conv1, net.conv2, net.conv3, net.fc1, net.fc2):
        assert torch.count_nonzero(m.bias) == 0


def _terrain_like(n: int, seed: int = 0) -> np.ndarray:
    """Sparse images as a walk gives them: a thick profile line, some stray pixels, and
    one empty image."""
    rng = np.random.default_rng(seed)
    images = np.zeros((n, 100, 100), np.uint8)
    for img in images[1:]:
        cols = np.arange(100)
        rows = np.clip(
            60 + rng.integers(-15, 15) + (cols * rng.uniform(-0.3, 0.3)).astype(int), 0, 97
        )
        for t in range(3):
            img[rows + t, cols] = 1
        img[rng.integers(0, 100, 10), rng.integers(0, 100, 10)] = 1
    return images


@pytest.mark.parametrize("busy", [-1.0, 1.0], ids=["dense", "sparse"])
def test_fast_cpu_paths_match_the_network(monkeypatch, busy):
    monkeypatch.setattr("inference.model.BUSY", busy)  # force one path
    net = _trained_looking()
    clf = Classifier(net)
    images = np.concatenate([_images(10), _terrain_like(10)])
    probs = clf.predict_batch(images, batch_size=7)
    with torch.no_grad():
        ref = torch.softmax(net(torch.from_numpy(images).float().unsqueeze(1)), 1).numpy()
    assert probs.shape == (20, 5)
    np.testing.assert_allclose(probs, ref, atol=1e-5)
    assert np.ptp(probs[:, 0]) > 1e-3  # images are told apart
    np.testing.assert_allclose(probs.sum(axis=1), 1.0)


def _band(first: int, last: int, seed: int = 0) -> np.ndarray:
    """A sparse image whose occupied cells lie in rows first..last only, touching both."""
    rng = np.random.default_rng(seed)
    img = np.zeros((100, 100), np.uint8)
    rows = np.arange(first, last + 1)
    img[rows, rng.integers(0, 100, len(rows))] = 1  # every row of the band
    img[rng.integers(first, last + 1, 30), rng.integers(0, 100, 30)] = 1
    return img


def _network_probs(net: TerrainCNN, images: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return torch.softmax(net(torch.from_numpy(images).float().unsqueeze(1)), 1).numpy()


def test_the_sparse_path_works_on_the_band_of_rows_an_image_occupies():
    """The sparse path computes only the rows the occupied band changes: bands at the top
    and bottom edges, one row, odd and even ends, alone and in batches of unlike bands."""
    net = _trained_looking()
    clf = Classifier(net)
    bands = [(0, 0), (0, 7), (99, 99), (93, 99), (41, 41), (40, 43), (25, 80), (1, 98)]
    images = np.stack(
        [_band(a, b, seed=i) for i, (a, b) in enumerate(bands)] + [np.zeros((100, 100), np.uint8)]
    )
    ref = _network_probs(net, images)
    one = np.stack([clf.predict(img) for img in images])
    np.testing.assert_allclose(one, ref, atol=1e-5)
    np.testing.assert_allclose(clf.predict_batch(images, batch_size=4), ref, atol=1e-5)
    assert np.ptp(ref[:, 0]) > 1e-3  # the bands give different scores


def test_predict_one_frame_equals_batched_and_checks_shapes():
    clf = Classifier(_trained_looking())
    images = _images(5, seed=1)
    batch = clf.predict_batch(images, batch_size=2)
    one = np.stack([clf.predict(img) for img in images])
    assert one.shape == (5, 5) and one.dtype == np.float64
    np.testing.assert_allclose(one, batch, atol=1e-6)
    np.testing.assert_allclose(clf.predict(images[0].astype(bool)), one[0], atol=1e-9)
    np.testing.assert_allclose(clf.predict(images[0] * 255), one[0], atol=1e-9)
    with pytest.raises(InferenceError, match="100 x 100"):
        clf.predict(np.zeros((50, 50)))
    with pytest.raises(InferenceError, match="one image"):
        clf.predict(images)
    assert clf.predict_batch(np.zeros((0, 100, 100))).shape == (0, 5)


def test_save_and_load_round_trip(tmp_path):
    net = _trained_looking(hidden=8)
    path = save_model(net, tmp_path / "m.pt", {"data": {"sessions": 3}})
    meta = json.loads(metadata_path(path).read_text())
    assert meta["classes"] == list(MODES) and meta["input_size"] == [100, 100]
    assert meta["architecture"]["hidden"] == 8 and len(meta["weights_sha256"]) == 64
    assert meta["data"] == {"sessions": 3}
    clf = load_classifier(str(path), device="cpu")
    images = _images(4)
    np.testing.assert_allclose(
        clf.predict_batch(images), Classifier(net).predict_batch(images), atol=1e-6
    )
    assert clf.metadata["weights_sha256"] == meta["weights_sha256"]
    assert load_classifier(str(metadata_path(path))).path == str(path)  # the .json works too


def _one_line(e: pytest.ExceptionInfo) -> str:
    msg = str(e.value)
    assert "\n" not in msg and msg
    return msg


def test_missing_file_is_one_clear_error(tmp_path):
    with pytest.raises(InferenceError) as e:
        load_classifier(str(tmp_path / "nowhere.pt"))
    assert "not found" in _one_line(e)
    path = save_model(_trained_looking(), tmp_path / "m.pt")
    metadata_path(path).unlink()
    with pytest.raises(InferenceError) as e:
        load_classifier(str(path))
    assert "metadata not found" in _one_line(e)


def test_corrupt_file_is_one_clear_error(tmp_path):
    path = save_model(_trained_looking(), tmp_path / "m.pt")
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(InferenceError) as e:
        load_classifier(str(path))
    assert "corrupt" in _one_line(e)
    # Garbage whose hash was (wrongly) recorded: torch cannot read it.
    path.write_bytes(b"not a zip file at all")
    meta = json.loads(metadata_path(path).read_text())
    import hashlib

    meta["weights_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    metadata_path(path).write_text(json.dumps(meta))
    with pytest.raises(InferenceError) as e:
        load_classifier(str(path))
    assert "corrupt" in _one_line(e)
    metadata_path(path).write_text("{ not json")
    with pytest.raises(InferenceError) as e:
        load_classifier(str(path))
    assert "corrupt" in _one_line(e)


def test_pickled_code_is_refused(tmp_path):
    """weights_only=True: a file that would run code on load is rejected, not executed."""
    path = tmp_path / "evil.pt"

    class Evil:
        def __reduce__(self):
            return (exec, ("import pathlib; pathlib.Path('pwned').touch()",))

    torch.save({"x": Evil()}, path)
    save_model(_trained_looking(), tmp_path / "ok.pt")
    meta = json.loads((tmp_path / "ok.json").read_text())
    import hashlib

    meta["weights_sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    (tmp_path / "evil.json").write_text(json.dumps(meta))
    with pytest.raises(InferenceError) as e:
        load_classifier(str(path))
    _one_line(e)
    assert not (tmp_path / "pwned").exists()


def test_mismatched_file_is_one_clear_error(tmp_path):
    path = save_model(_trained_looking(hidden=8), tmp_path / "m.pt")
    meta = json.loads(metadata_path(path).read_text())
    # Metadata says 16 hidden units, the weights have 8.
    metadata_path(path).write_text(json.dumps({**meta, "architecture": {"hidden": 16}}))
    with pytest.raises(InferenceError) as e:
        load_classifier(str(path))
    assert "does not match" in _one_line(e)
    metadata_path(path).write_text(json.dumps({**meta, "classes": ["A", "B"]}))
    with pytest.raises(InferenceError) as e:
        load_classifier(str(path))
    assert "classifies" in _one_line(e)
    metadata_path(path).write_text(json.dumps({**meta, "input_size": [64, 64]}))
    with pytest.raises(InferenceError) as e:
        load_classifier(str(path))
    assert "64" in _one_line(e)
    # A state dict of some other network.
    torch.save({"weight": torch.zeros(3)}, path)
    import hashlib

    metadata_path(path).write_text(
        json.dumps({**meta, "weights_sha256": hashlib.sha256(path.read_bytes()).hexdigest()})
    )
    with pytest.raises(InferenceError) as e:
        load_classifier(str(path))
    assert "does not match" in _one_line(e)


@pytest.mark.slow
def test_bench_cnn_reports_its_figures():
    from capture.bench.components import bench_cnn

    result = bench_cnn(frames=20)
    assert set(result) == {
        "cnn_frame_ms",
        "cnn_frame_busy_ms",
        "cnn_batch_rate",
        "walk_patches_occupied",
        "walk_band_rows",
    }
    assert min(result.values()) > 0
    # A walk's images are sparse and fill a band: what the sparse path's cost rests on.
    assert result["walk_patches_occupied"] < BUSY and result["walk_band_rows"] < 0.5


def test_the_bundled_model_is_small_loads_safely_and_is_the_default():
    assert BUNDLED_PATH.is_file() and BUNDLED_PATH.stat().st_size < 8e6
    clf = load_classifier(None, device="cpu")
    assert clf.path == str(BUNDLED_PATH) and load_classifier("").path == str(BUNDLED_PATH)
    meta = clf.metadata
    assert meta["data"]["train"]["sessions"] > 0
    assert {"indoor", "outdoor"} <= set(meta["metrics"]["test"])
    probs = clf.predict(np.zeros((100, 100), np.uint8))
    assert probs.shape == (5,) and probs.sum() == pytest.approx(1.0)
    # A level floor seen from the side, in the rows it takes in the simulator's images at the
    # thigh's height (94-98), is level ground.
    floor = np.zeros((100, 100), np.uint8)
    floor[94:97, 1:99] = 1
    assert MODES[int(np.argmax(clf.predict(floor)))] == "LG"
