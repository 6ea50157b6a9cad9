"""Every simulated signal within what a thigh and an MTi can do.

The IMU emulator and `walkcap synth` take the rate of turn from the walk's orientation
change over a few milliseconds, so any jump in the walker's pose (the course looping, the
walk begun anew) would be a rate of turn of tens of rad/s.
"""

import numpy as np
import pytest

from capture.corpus.synth import imu_samples
from devices.rotations import quat_conjugate, quat_multiply
from devices.simulator import Simulator
from devices.simulator.camera import MockCamera
from devices.simulator.course import make_course

# A thigh in walking turns at up to ~5 rad/s; a quick high knee lift (the simulator's "sky"
# error image) nearer 9. The MTi 1-series' gyroscopes read up to 2000 deg/s (35 rad/s).
MAX_RATE_RAD_S = 10.0
GRAVITY = 9.81
H = 0.002  # the emulator's central difference (devices.imu.emulator.samples)


def body_rates(orientation_at, t: np.ndarray) -> np.ndarray:
    """|rate of turn| (rad/s) from the orientation at t - H and t + H, as the emulator does."""
    rates = []
    for ti in t:
        dq = quat_multiply(quat_conjugate(orientation_at(ti - H)), orientation_at(ti + H))
        rates.append(np.linalg.norm(dq[1:]) / H * np.sign(dq[0] or 1.0))
    return np.abs(np.array(rates))


@pytest.mark.parametrize("preset", ["indoor", "outdoor"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_looping_course_never_jumps_the_thigh(preset, seed):
    """Around the wrap of a looping course (and so where a restarted walk begins), as the
    emulator differentiates the mock camera's orientation_at."""
    simulator = Simulator(make_course(preset, seed), seed=seed, events=[])
    camera = MockCamera(simulator=simulator, loop=True, realtime=False)
    d = simulator.duration_s
    t = np.concatenate(
        [np.arange(d - 0.05, d + 0.05, 0.0005), np.arange(2 * d - 0.02, 2 * d, 0.001)]
    )
    rates = body_rates(camera.orientation_at, t)
    assert rates.max() < MAX_RATE_RAD_S, f"{rates.max():.1f} rad/s at the wrap"
    # seamless: the walk ends in its first pose, and the rate of turn goes on across the
    # wrap as it does elsewhere (a step of a few hundredths of a degree would be a glitch
    # of a rad/s in one IMU sample, which the gait detector takes for the end of a swing)
    q0, q_end = camera.orientation_at(0.0), camera.orientation_at(d - 1e-9)
    assert np.degrees(2 * np.arccos(min(1.0, abs(float(np.dot(q0, q_end)))))) < 0.01
    before = np.arange(d - 0.05, d - 0.01, 0.0005)
    jump = np.abs(np.diff(rates[: len(before) + 40]))
    assert jump.max() < 0.1, f"the rate of turn jumps {jump.max():.2f} rad/s at the wrap"


@pytest.mark.parametrize("preset, seed", [("indoor", 0), ("outdoor", 3)])
def test_every_imu_sample_of_a_walk_is_physical(preset, seed):
    """The synthesized IMU (synth's samples, the emulator's formulas) over a whole walk
    with its error images: rate of turn, acceleration (gravity: the walk's accelerations are
    not simulated) and the step of the orientation between samples."""
    simulator = Simulator(make_course(preset, seed), seed=seed)
    rate_hz = 100.0
    samples = list(imu_samples(simulator, rate_hz, np.random.default_rng(seed), 0))
    gyro = np.array([s.rate_of_turn for s in samples])
    accel = np.array([s.acceleration for s in samples])
    quats = np.array([s.quaternion for s in samples])
    assert np.linalg.norm(gyro, axis=1).max() < MAX_RATE_RAD_S
    assert np.all(np.abs(np.linalg.norm(accel, axis=1) - GRAVITY) < 0.5)
    dots = np.abs(np.einsum("ij,ij->i", quats[1:], quats[:-1]))
    steps = 2 * np.arccos(np.clip(dots, -1.0, 1.0))
    assert steps.max() < MAX_RATE_RAD_S / rate_hz
    # the emulator's central difference over the whole walk, every 5 ms
    t = np.arange(0.0, simulator.duration_s, 0.005)
    assert body_rates(simulator.thigh_quaternion, t).max() < MAX_RATE_RAD_S


def test_a_camera_stopped_mid_walk_eases_the_thigh_back_to_standing():
    """The mock rig's IMU across a stop of the camera mid-walk and a new start: no jump."""
    from devices.simulator.rig import StandingBlend

    simulator = Simulator(make_course("indoor", 0), seed=0, events=[])
    blend = StandingBlend(simulator.thigh_quaternion)
    stop, restart = 7.3, 9.0  # IMU seconds; the walk began at 0

    def thigh(t: float) -> np.ndarray:
        return blend(t, t if t < stop else (t - restart if t >= restart else None))

    rates = body_rates(thigh, np.arange(stop - 0.2, restart + 0.2, 0.0025))  # in time order
    assert rates.max() < MAX_RATE_RAD_S, f"{rates.max():.1f} rad/s"
    blend = StandingBlend(simulator.thigh_quaternion)
    for t in np.arange(stop - 0.2, stop + StandingBlend.EASE_S + 0.1, 0.01):
        q = thigh(t)
    assert abs(np.dot(q, simulator.thigh_quaternion(0.0))) > 0.9999  # standing again
