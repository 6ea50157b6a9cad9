"""Read one walkcap recording: what it holds, and its per-frame table.

    python examples/read_recording.py recordings/S07_indoor_t03.mcap

A recording is one MCAP file per trial. `open_recording` gives its metadata and topics
(and reads a damaged or cut-off file as far as it goes); `read_trial` joins the per-frame
topics into arrays, one row per classified frame.
"""

import sys

import numpy as np

from capture.recording import open_recording, read_trial

path = sys.argv[1]

rec = open_recording(path)
session = rec.metadata.get("session", {})
print(f"{rec.path.name}: {rec.duration_s:.1f} s, complete: {rec.complete}")
print(f"subject {session.get('subject')}, condition {session.get('condition')}")
for topic, info in sorted(rec.topics.items()):
    print(f"  {topic:28s} {info.count:6d} messages")

# Raw messages, topic by topic: here the first IMU sample (the thigh's orientation).
first_imu = next(rec.messages(["/imu"]), None)
if first_imu is not None:
    print("first IMU quaternion (w, x, y, z):", first_imu.data["quaternion"])

# The per-frame table: every array has one entry per classified frame.
trial = read_trial(path)
modes = trial["modes"]  # mode names, in the order of the probability columns
n = len(trial["frame_index"])
print(f"{n} classified frames")

# Accuracy of the live (fused) decision against the terrain each image shows, where
# the recording has that reference (a simulator's truth, or labels made offline).
terrain = trial["terrain"]
if terrain is not None:
    known = (terrain >= 0) & (trial["decisions"] >= 0)
    agree = np.mean(trial["decisions"][known] == terrain[known]) if known.any() else float("nan")
    print(f"fused decision = terrain on {100 * agree:.1f} % of {known.sum()} frames")

# How long the subject spent in each mode, as the operator keyed it live.
labels = trial["labels"]
for k, mode in enumerate(modes):
    print(f"  {mode}: {np.sum(labels == k)} frames")
