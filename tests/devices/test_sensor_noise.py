"""The ToF model against the pico flexx datasheet and royale's invalid-pixel rules."""

import numpy as np
import pytest

from devices.frames import CameraGeometry
from devices.simulator.render import Hits, ToFParams, ToFSensor, datasheet_noise, use_case
from devices.simulator.sensor_check import facing_noise, level_band


def test_use_cases_and_their_datasheet_noise():
    assert use_case(15.0)[0] == "MODE_9_15FPS_700"  # the paper's rate
    assert use_case(40.0)[0] == "MODE_5_45FPS_500"
    assert datasheet_noise(5.0) == pytest.approx(0.01)
    assert datasheet_noise(45.0) == pytest.approx(0.02)
    rates = [5.0, 10.0, 15.0, 25.0, 45.0]
    noise = [datasheet_noise(f) for f in rates]
    assert noise == sorted(noise)  # less integration time, more noise


@pytest.mark.parametrize(
    ("fps", "distances", "figure"), [(5.0, (0.5, 1.0, 2.0, 3.5), 0.01), (45.0, (0.2, 1.0), 0.02)]
)
def test_noise_on_a_surface_facing_the_camera_is_the_datasheets(fps, distances, figure):
    for d in distances:
        measured = facing_noise(fps, d, frames=4)
        assert figure * 0.9 <= measured <= figure * 1.03, (d, measured)


@pytest.mark.parametrize("forward", [0.5, 1.0, 2.0])
def test_level_ground_band_at_the_paper_rate(forward):
    band = level_band(forward, fps=15.0, frames=8)
    # Depth noise along the rays as the model states it (the noise is correlated over 3 x 3
    # pixels, so a few frames estimate it to about 10 %): the datasheet's figure for
    # MODE_9_15FPS_700, and at 2 m up to 13 % more for the floor's weaker, grazing return.
    assert band.sigma_depth_m == pytest.approx(band.expected_sigma_depth_m, rel=0.15)
    assert band.expected_sigma_depth_m / band.range_m <= datasheet_noise(15.0) * 1.15
    # Height spread = depth noise x sin(depression): under a centimetre, a band of at most
    # 5 one-centimetre rows in the classifier's image.
    assert band.sigma_height_m == pytest.approx(
        band.sigma_depth_m * np.sin(np.radians(band.depression_deg)), rel=0.15
    )
    assert band.sigma_height_m < 0.01 and band.rows <= 5
    assert band.valid_share > 0.9


def _edge_hits(g, near=0.6, far=1.6):
    rays = g.rays().reshape(-1, 3)
    rows = np.arange(len(rays)) // g.width
    z = np.where(rows > g.height // 2, near, far)  # near plane below, far plane above
    t = (z / rays[:, 2]).astype(np.float32)
    return Hits(t, np.zeros(len(t), np.int32), rays[:, 2].copy(), np.full_like(t, 0.45))


def test_flying_pixels_mix_at_edges_and_royales_filter_drops_the_ones_between():
    g = CameraGeometry()
    params = ToFParams.for_scene(False, 15.0)
    sensor = ToFSensor(g, params, seed=1)
    rng = np.random.default_rng(2)
    between = kept_between = 0
    for _ in range(5):
        xyz, confidence, _ = sensor.apply(_edge_hits(g), rng)
        z = xyz[..., 2]
        ok = confidence > 0
        edge_rows = slice(g.height // 2 - 1, g.height // 2 + 3)
        # Pixels at the edge measure between the two surfaces before the filter ...
        between += int(((z[edge_rows] > 0.7) & (z[edge_rows] < 1.5)).sum() + (~ok[edge_rows]).sum())
        kept_between += int((ok & (z > 0.7) & (z < 1.5)).sum())
        # ... and no pixel left differs from both neighbours above and below by more than
        # royale's threshold.
        c, up, down = z[1:-1], z[:-2], z[2:]
        both = ok[1:-1] & ok[:-2] & ok[2:]
        thr = params.flying_threshold(c)
        assert not np.any(both & (np.abs(c - up) > thr) & (np.abs(c - down) > thr))
    assert between > 5 * g.width  # the edge row of every frame
    assert kept_between < 0.1 * between
    # Away from the edge everything is valid.
    assert ok[: g.height // 2 - 3].mean() > 0.99 and ok[g.height // 2 + 4 :].mean() > 0.99


def test_pixels_noisier_than_royales_threshold_are_invalid():
    g = CameraGeometry()
    params = ToFParams.for_scene(True, 45.0)  # outdoors, the noisiest use case
    sensor = ToFSensor(g, params, seed=0)
    rays = sensor.rays_cam
    t = (3.5 / rays[:, 2]).astype(np.float32)
    cos = np.full_like(t, 0.5)  # a dark surface, far and oblique
    hits = Hits(t, np.zeros(len(t), np.int32), cos, np.full_like(t, 0.3))
    amplitude = 0.3 * cos * sensor.vignetting / t**2
    sigma = params.noise_sigma(t, amplitude)
    _, confidence, _ = sensor.apply(hits, np.random.default_rng(0))
    noisy = (sigma > params.max_noise_m) & (amplitude > params.min_amplitude)
    assert noisy.sum() > 100
    assert np.all(confidence.ravel()[noisy] == 0)
