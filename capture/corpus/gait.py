"""`walkcap eval gait`: the IMU's gait events against the simulator's, one recording a task.

The detector (inference.gait) runs again on the recording's /imu, so what is judged is the
detector as it is now (`recorded=True` judges the /gait the file holds instead), against
/sim/gait: each true heel contact (toe off) counts as detected when a detected one lies
within the tolerance, one-to-one; every detection left over is a false one.
"""

from __future__ import annotations

import os

import numpy as np

from capture.errors import CaptureError
from capture.recording import topics as T
from capture.recording.gait import gait_table, read_gait
from capture.recording.reader import imu_sample, open_recording
from devices.frames import GAIT_EVENTS, MODES
from inference.gait import detect, match_events, score_events


def gait_evaluation(path: str | os.PathLike, tolerance_ms: float, recorded: bool = False) -> dict:
    """One recording's gait events judged: {"file", "condition", "scores": {event:
    EventScore}, "heel_contacts_by_mode": {mode: (true, detected within the tolerance)}};
    CaptureError without /sim/gait (nothing to judge against)."""
    rec = open_recording(path)
    if T.SIM_GAIT not in rec.topics:
        raise CaptureError(f"{path}: no {T.SIM_GAIT} (a simulated recording has the truth)")
    truth = read_gait(rec, source="simulator")
    if recorded:
        found = read_gait(rec, source="imu")
    else:
        found = gait_table(detect(imu_sample(m.data) for m in rec.messages([T.IMU])))
    tolerance_ns = int(round(tolerance_ms * 1e6))
    scores, by_mode = {}, {}
    for event in GAIT_EVENTS:
        t, f = truth.of(event=event), found.of(event=event)
        scores[event] = score_events(t.time_ns, f.time_ns, tolerance_ns)
        if event == "heel_contact":  # the terrain under the foot: where detection fails
            hit = np.zeros(len(t), dtype=bool)
            hit[[i for i, _ in match_events(t.time_ns, f.time_ns, tolerance_ns)]] = True
            for mode in MODES:
                mine = t.mode == mode
                if mine.any():
                    by_mode[mode] = (int(mine.sum()), int(hit[mine].sum()))
    return {
        "file": str(path),
        "condition": str(rec.metadata.get("session", {}).get("condition") or ""),
        "scores": scores,
        "heel_contacts_by_mode": by_mode,
    }


def totals(results: list[dict]) -> dict[str, dict]:
    """Per condition and over all ("all"): scores summed per event kind ("scores") and
    heel contacts (true, detected) per mode ("heel_contacts_by_mode")."""
    out: dict[str, dict] = {}
    for r in results:
        for group in (r["condition"] or "?", "all"):
            mine = out.setdefault(group, {"scores": {}, "heel_contacts_by_mode": {}})
            for event, score in r["scores"].items():
                have = mine["scores"].get(event)
                mine["scores"][event] = have + score if have is not None else score
            for mode, (n, hit) in r["heel_contacts_by_mode"].items():
                n0, hit0 = mine["heel_contacts_by_mode"].get(mode, (0, 0))
                mine["heel_contacts_by_mode"][mode] = (n0 + n, hit0 + hit)
    return out
