"""The live session: devices in, the pipeline (level, classify, fuse) per frame, the operator's
labels, alarms and preflight checks, and the recorder fed as it goes.

Public API: `Session`, `Snapshot` (capture.live.session); `SubjectInfo`, `trial_file`
(capture.live.trials); `Pipeline`, `FrameResult`, `build_pipeline`, `software_metadata`
(capture.live.pipeline); `open_devices`, `close_devices` (capture.live.devices);
`LabelBook`, `LabelChange` (capture.live.labels); `FrameTimeline`, `TimelineEntry`
(capture.live.timeline); `TrialAlarms` (capture.live.alarms); `preflight` checks
(capture.live.preflight); `ReplayCamera` (capture.live.replay_camera). Import them from
their modules: each pulls in only what it needs.
"""
