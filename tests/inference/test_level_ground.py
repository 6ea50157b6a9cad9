"""Level ground is level: the fitted slope of simulated level-ground frames, over many
frames of sessions never used to design the fit (the statistics of issue 48).

Each session as `walkcap synth --format recording` makes it: the configured walker, the
IMU's orientation with the MTi 1-series' slowly drifting error, the nominal mounting, the
pipeline's preprocessing and terrain features (hinted with the truth's mode, as a correct
fused decision would).
"""

import numpy as np
import pytest

from devices.config import MountingConfig, SimulatorConfig
from devices.orientation_error import OrientationError, OrientationErrorModel
from devices.simulator import Simulator
from inference.config import PreprocessConfig
from inference.features import terrain_features
from inference.preprocess import preprocess_frame

SESSIONS = 8  # a preset
SEED = 48_900
EVERY = 3  # every third frame: 5 a second


def level_ground_slopes(preset: str) -> np.ndarray:
    params, mounting = PreprocessConfig(), MountingConfig()
    slopes = []
    for i in range(SESSIONS):
        seed = SEED + i
        sim = Simulator.from_config(SimulatorConfig(course=preset, seed=seed), cast_threads=1)
        error = OrientationError(OrientationErrorModel(), np.random.default_rng([seed, 4242]))
        for k in range(0, int(sim.duration_s * 15), EVERY):
            t = k / 15
            frame = sim.render(t, k)
            q = error.apply(np.asarray(frame.truth["thigh_quaternion"]), t)
            if frame.truth["mode"] != "LG":
                continue
            pre = preprocess_frame(frame, q, params, mounting=mounting)
            if not pre.ok:
                continue
            slope = terrain_features(pre.profile, "LG", params.max_forward_m).slope_deg
            if slope is not None:
                slopes.append(slope)
    return np.array(slopes)


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["indoor", "outdoor"])
def test_simulated_level_ground_fits_as_level(preset):
    slopes = level_ground_slopes(preset)
    assert len(slopes) >= 200
    beyond = float(np.mean(np.abs(slopes) > 3.0))
    median = float(np.median(slopes))
    assert abs(median) <= 1.0, f"{preset}: median {median:+.2f} deg"
    assert beyond <= 0.10, f"{preset}: {beyond:.0%} beyond 3 deg (median {median:+.2f})"
