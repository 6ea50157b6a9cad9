"""The session's optional connections to the lab's tools: LSL outlets and inlets
(capture.labtools.lsl), LabRecorder-style remote control (capture.labtools.remote), a live
Foxglove server (capture.labtools.foxglove_live), started together by
capture.labtools.connections.LabTools. Each is optional: pylsl and foxglove-sdk load only when
their tool is asked for.
"""
