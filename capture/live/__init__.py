"""The live session: devices in, the pipeline (level, classify, fuse) per frame, the operator's
labels, alarms and preflight checks, and the recorder fed as it goes.

Public API: `Session`, `Snapshot`, `SubjectInfo` (capture.live.session); `Pipeline`,
`FrameResult` (capture.live.pipeline); `TrialAlarms` (capture.live.alarms); `preflight`
checks (capture.live.preflight); `ReplayCamera` (capture.live.replay_camera). Import them from
their modules: each pulls in only what it needs.
"""
