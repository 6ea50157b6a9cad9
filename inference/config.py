"""The algorithms' parameter sets, one dataclass each: [preprocess], [model], [fusion].

These are what the algorithms take (`inference.preprocess` a PreprocessConfig, the fusion
methods a FusionConfig) and the configuration's sections: capture.config builds each from
its TOML table, validating each key by the type of its field here, then by its range (each
section's `problems()`). Each key is documented once, in its field (`devices.config.key`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from devices.config import Problems, choice_problems, key, number_in
from inference import fusion_design as design  # the authors' matrix and the designs, defined once
from inference.fusion import Fusion, make_fusion


@dataclass
class PreprocessConfig:
    """From a depth frame and the IMU orientation to the CNN's binary image
    (inference.preprocess); the camera's mounting on the IMU is [mounting]."""

    corridor_width_m: float = key(
        0.1, "width of the walking corridor kept, across the direction, metres (authors: 0.1)"
    )
    min_forward_m: float = key(0.0, "nearest point kept ahead of the camera, metres")
    # 2.5 m, not 1.5: a thigh camera at peak flexion or above a descent sees its nearest
    # corridor point 1-2 m ahead; a 1.5 m crop leaves 7-9 % of frames empty or a few cm
    # long (a third of the classifier's errors). The image is still 1 m from the nearest.
    max_forward_m: float = key(2.5, "farthest point kept ahead of the camera, metres")
    min_height_m: float = key(-2.0, "lowest point kept, relative to the camera, metres")
    max_height_m: float = key(1.0, "highest point kept, relative to the camera, metres")
    grid_size: int = key(100, "the CNN's image is grid_size x grid_size cells")
    cell_m: float = key(0.01, "cell size of the image, metres")
    min_confidence: int = key(
        1, "lowest camera confidence a point needs to be used (royale: 0 = invalid)"
    )
    # numpy counts the 3 x 3 sagittal cells of outlier_cell_m around a point; open3d a
    # sphere of radius 1.5 * outlier_cell_m
    outlier_min_points: int = key(
        4, "isolated-point removal: neighbours needed in 3 x 3 cells, itself included (0: off)"
    )
    outlier_cell_m: float = key(0.01, "isolated-point removal: cell size, metres")
    max_elevation_deg: float = key(
        30.0, "camera looking higher than this above level: no image, degrees"
    )
    # an unplugged or silent IMU; 50 ms: five periods at 100 Hz
    max_orientation_age_ms: float = key(
        50.0, "IMU orientation older than this: stale_orientation, no image, no decision, ms"
    )
    min_points: int = key(10, "fewer corridor points than this: an empty image (empty_corridor)")
    backend: str = key(
        "numpy",
        "point-cloud backend: each gives the same result, numpy faster",
        choices="inference.preprocess:BACKENDS",
    )

    def problems(self) -> Problems:
        out = choice_problems(self)
        if not number_in(self.corridor_width_m, 0.0, 10.0, low_open=True):
            out.append(("corridor_width_m", "0 < corridor_width_m <= 10"))
        if not number_in(self.min_forward_m, 0.0, 20.0):
            out.append(("min_forward_m", "0 to 20 m"))
        if not number_in(self.max_forward_m, self.min_forward_m, 20.0, low_open=True):
            out.append(("max_forward_m", "min_forward_m < max_forward_m <= 20 m"))
        if not number_in(self.min_height_m, -20.0, 20.0):
            out.append(("min_height_m", "-20 to 20 m"))
        if not number_in(self.max_height_m, self.min_height_m, 20.0, low_open=True):
            out.append(("max_height_m", "min_height_m < max_height_m <= 20 m"))
        if not 2 <= self.grid_size <= 2000:
            out.append(("grid_size", "2 to 2000 cells"))
        if not number_in(self.cell_m, 0.0, 1.0, low_open=True):
            out.append(("cell_m", "0 < cell_m <= 1 m"))
        if not 0 <= self.min_confidence <= 255:
            out.append(("min_confidence", "0 to 255"))
        if not 0 <= self.outlier_min_points <= 9:
            out.append(("outlier_min_points", "0 (off) to 9 points of a 3 x 3 neighbourhood"))
        if not number_in(self.outlier_cell_m, 0.0, 1.0, low_open=True):
            out.append(("outlier_cell_m", "0 < outlier_cell_m <= 1 m"))
        if not number_in(self.max_elevation_deg, 0.0, 90.0):
            out.append(("max_elevation_deg", "0 to 90 degrees"))
        if not number_in(self.max_orientation_age_ms, 0.0, 10_000.0, low_open=True):
            out.append(("max_orientation_age_ms", "0 < max_orientation_age_ms <= 10000 ms"))
        if not 0 <= self.min_points <= 1_000_000:
            out.append(("min_points", "0 to 1000000 points"))
        return out


@dataclass
class ModelConfig:
    """The terrain classifier (inference.model)."""

    path: str = key("", "classifier weights (.pt); empty: the bundled model")
    device: str = key(
        "auto",
        "where the CNN runs: auto takes cuda when there is one",
        choices=("auto", "cpu", "cuda"),
    )

    def problems(self) -> Problems:
        return choice_problems(self)


@dataclass
class FusionConfig:
    """The streaming fusion of the CNN's outputs (inference.fusion): the live session's
    method and every method's parameters, which `walkcap eval` uses too."""

    method: str = key(
        "hmm+voting",
        "the live session's fusion: hmm+voting (the paper's), steady (switches once a "
        "terrain change) or another of eval's methods",
        choices="inference.fusion:METHODS",
    )
    window: int = key(5, "HMM smoothing window l_w, frames")
    vote_delay: int = key(1, "voting half-window l_v, frames (decisions lag by this many)")
    transition: list[list[float]] = key(
        doc="HMM transition matrix (the paper's), rows and columns LG US DS UR DR",
        factory=lambda: design.PAPER_TRANSITION.tolist(),
    )
    lag: int = key(1, "fixed-lag: frames the smoother waits for (its decision delay)")
    stay: float = key(
        design.STEADY_STAY,
        "steady: per-frame stay probability (0.987: a terrain held ~5 s at 15 fps)",
    )
    evidence: float = key(
        design.STEADY_EVIDENCE,
        "steady: each frame's CNN probabilities to this power (its errors come in runs of "
        "1.34 frames)",
    )
    hysteresis: float = key(
        design.HYSTERESIS,
        "steady+hysteresis: the posterior level ground needs before the decision leaves "
        "stairs or a ramp for it (0.8: 4 to 1 against the others)",
    )
    geometry_hysteresis: float = key(
        design.GEOMETRY_HYSTERESIS,
        "steady+geometry: the posterior level ground needs, the terrain features included, "
        "before the decision leaves stairs or a ramp for it (0.6)",
    )
    geometry_evidence: float = key(
        design.GEOMETRY_EVIDENCE,
        "steady+geometry: each frame's terrain-feature likelihood to this power (their "
        "misreads come in runs of 2.7 frames)",
    )

    def make(self, method: str | None = None) -> Fusion:
        """A fresh streaming object of `method` (default: this configuration's)."""
        return make_fusion(
            method or self.method,
            self.window,
            self.vote_delay,
            self.transition,
            self.lag,
            self.stay,
            self.evidence,
            self.hysteresis,
            self.geometry_hysteresis,
            self.geometry_evidence,
        )

    def delay_frames(self, method: str | None = None) -> int:
        return self.make(method).delay_frames

    def problems(self) -> Problems:
        out = choice_problems(self)
        if not number_in(self.stay, 0.2, 1.0, low_open=True) or self.stay >= 1.0:
            out.append(("stay", "0.2 < stay < 1 (a mode must be left more rarely than kept)"))
        if not number_in(self.evidence, 0.0, 1.0, low_open=True):
            out.append(("evidence", "0 < evidence <= 1"))
        if not number_in(self.hysteresis, 0.0, 1.0) or self.hysteresis >= 1.0:
            out.append(("hysteresis", "0 <= hysteresis < 1"))
        if not number_in(self.geometry_hysteresis, 0.0, 1.0) or self.geometry_hysteresis >= 1.0:
            out.append(("geometry_hysteresis", "0 <= geometry_hysteresis < 1"))
        if not number_in(self.geometry_evidence, 0.0, 1.0, low_open=True):
            out.append(("geometry_evidence", "0 < geometry_evidence <= 1"))
        if not 1 <= self.window <= 1000:
            out.append(("window", "1 to 1000 frames"))
        if not 0 <= self.vote_delay <= 1000:
            out.append(("vote_delay", "0 to 1000 frames"))
        if not 0 <= self.lag <= 1000:
            out.append(("lag", "0 to 1000 frames"))
        rows = self.transition
        shape_ok = len(rows) == design.N_MODES and all(len(r) == design.N_MODES for r in rows)
        values_ok = shape_ok and all(math.isfinite(v) and v >= 0 for r in rows for v in r)
        if not (values_ok and all(sum(r) > 0 for r in rows)):
            out.append(
                (
                    "transition",
                    f"{design.N_MODES} rows of {design.N_MODES} finite, non-negative numbers, "
                    "each row with a positive sum",
                )
            )
        return out
