"""The terrain-walk simulator and the mock camera built on it.

course = make_course("indoor", seed=0)      # segments: LG, US, DS, LG, UR, DR, LG
sim = Simulator(course)                     # walker + ray-cast ToF camera
frame = sim.render(1.0)                     # DepthFrame, ground truth in frame.truth
q = sim.thigh_quaternion(1.0)               # what the IMU on the thigh should report
"""

from devices.simulator.camera import MockCamera
from devices.simulator.course import PAPER_TRIAL, PRESETS, Box, Course, Segment, make_course
from devices.simulator.simulator import Simulator
from devices.simulator.walk import ERROR_KINDS, ErrorEvent, Walk

__all__ = [
    "MockCamera",
    "PAPER_TRIAL",
    "PRESETS",
    "Box",
    "Course",
    "Segment",
    "make_course",
    "Simulator",
    "ERROR_KINDS",
    "ErrorEvent",
    "Walk",
]
