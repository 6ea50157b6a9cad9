"""Listen to a running walkcap session over Lab Streaming Layer (pylsl).

    python examples/listen_lsl.py [--name walkcap] [--count 20]

Start a session with LSL outlets (`walkcap tui --lsl`, or `[lsl] enabled = true` in
walkcap.toml), then run this on any machine of the lab network. walkcap sends three streams:
"<name> IMU" (10 channels), "<name> Terrain" (the classifier per frame) and
"<name> Markers" (labels and operator markers). This prints the terrain stream's
decisions as they come, stamped on LSL's clock (the one LabRecorder's XDF files use).
"""

import argparse

import pylsl

parser = argparse.ArgumentParser()
parser.add_argument("--name", default="walkcap", help="the session's stream name prefix")
parser.add_argument("--count", type=int, default=20, help="samples to print, then stop")
parser.add_argument("--timeout", type=float, default=30.0, help="seconds to look for it")
args = parser.parse_args()

# Find the stream by name; resolve_byprop waits up to the timeout for it to appear.
found = pylsl.resolve_byprop("name", f"{args.name} Terrain", 1, args.timeout)
if not found:
    raise SystemExit(f"no LSL stream named {args.name} Terrain")
inlet = pylsl.StreamInlet(found[0])

# The channel names travel with the stream (XDF's desc/channels/channel/label).
info = inlet.info(timeout=5.0)
channel = info.desc().child("channels").child("channel")
labels = []
while not channel.empty():
    labels.append(channel.child_value("label"))
    channel = channel.next_sibling()
modes = info.desc().child("acquisition").child_value("modes").split()  # LG US DS UR DR
print("channels:", ", ".join(labels))

received = 0
while received < args.count:
    sample, lsl_time = inlet.pull_sample(timeout=args.timeout)
    if sample is None:
        raise SystemExit("the stream went quiet")
    values = dict(zip(labels, sample))
    decision = int(values["fused_decision"])  # -1 before the first decision
    print(
        f"t={lsl_time:.3f} frame {int(values['frame_index'])}: "
        f"CNN {modes[int(values['cnn_decision'])]}, "
        f"fused {modes[decision] if decision >= 0 else '-'}"
    )
    received += 1
