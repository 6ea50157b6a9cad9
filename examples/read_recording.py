"""Read one walkcap recording: what it holds, and its per-frame table.

    python examples/read_recording.py recordings/S07_indoor_t03.mcap

A recording is one MCAP file per trial. `open_recording` gives its metadata and topics
(and reads a damaged or cut-off file as far as it goes); `read_trial` gives its per-frame
table, one row per classified frame.
"""

import sys

import numpy as np

from capture.corpus.trials import read_trial
from capture.recording import open_recording

path = sys.argv[1]

with open_recording(path) as rec:
    session = rec.meta.session
    print(f"{rec.path.name}: {rec.duration_s:.1f} s, complete: {rec.complete}")
    print(f"subject {session.subject}, condition {session.condition}")
    for topic, info in sorted(rec.topics.items()):
        print(f"  {topic:28s} {info.count:6d} messages")

    # Raw messages, topic by topic: here the first IMU sample (the thigh's orientation).
    first_imu = next(rec.messages("/imu"), None)
    if first_imu is not None:
        print("first IMU quaternion (w, x, y, z):", first_imu.data["quaternion"])
        # a window of time: the IMU samples of the first second, read from its chunks only
        second = list(rec.messages("/imu", start=rec.start_ns, end=rec.start_ns + 10**9))
        print(f"{len(second)} IMU samples in the first second")

# The per-frame table: every array has one entry per classified frame.
trial = read_trial(path)
frames = trial.frames
modes = trial.MODES  # mode names, in the order of the probability columns
print(f"{len(frames)} classified frames")

# Accuracy of the live (fused) decision against the terrain each image shows, where
# the recording has that reference (a simulator's truth, or labels made offline).
terrain = frames.terrain
if terrain is not None:
    known = (terrain >= 0) & (frames.decision >= 0)
    agree = np.mean(frames.decision[known] == terrain[known]) if known.any() else float("nan")
    print(f"fused decision = terrain on {100 * agree:.1f} % of {known.sum()} frames")

# How long the subject spent in each mode, as the operator keyed it live.
labels = frames.labels
for k, mode in enumerate(modes):
    print(f"  {mode}: {np.sum(labels == k)} frames")
