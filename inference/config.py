"""The algorithms' configuration sections: [preprocess], [model], [fusion].

capture.config composes every package's sections into the one TOML file and validates
each key by the type of its field here, then by its range (each section's `problems()`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from devices.config import Problems, number_in, one_of
from inference.fusion import METHODS  # the methods and the authors' matrix, defined once
from inference.fusion_design import (
    HYSTERESIS,
    N_MODES,
    PAPER_TRANSITION,
    STEADY_EVIDENCE,
    STEADY_STAY,
)


@dataclass
class PreprocessConfig:
    corridor_width_m: float = 0.1  # across the walking direction (authors: 0.1 m)
    min_forward_m: float = 0.0
    max_forward_m: float = 2.5  # see inference.preprocess.PreprocessParams
    grid_size: int = 100  # 100 x 100 cells
    cell_m: float = 0.01  # 1 cm cells
    min_confidence: int = 1
    outlier_min_points: int = 4  # isolated-point removal, 3 x 3 cm neighbourhood (0: off)
    max_elevation_deg: float = 30.0  # camera looking higher than this: no image
    # an orientation farther than this from its nearest IMU sample (an unplugged or silent
    # IMU) is stale: no image, no decision. 50 ms: five periods at 100 Hz
    max_orientation_age_ms: float = 50.0
    backend: str = "numpy"  # numpy | open3d (same result; numpy is faster)

    def problems(self) -> Problems:
        out = one_of("backend", self.backend, ("numpy", "open3d"))
        if not number_in(self.corridor_width_m, 0.0, 10.0, low_open=True):
            out.append(("corridor_width_m", "0 < corridor_width_m <= 10"))
        if not number_in(self.min_forward_m, 0.0, 20.0):
            out.append(("min_forward_m", "0 to 20 m"))
        if not number_in(self.max_forward_m, self.min_forward_m, 20.0, low_open=True):
            out.append(("max_forward_m", "min_forward_m < max_forward_m <= 20 m"))
        if not 1 <= self.grid_size <= 2000:
            out.append(("grid_size", "1 to 2000 cells"))
        if not number_in(self.cell_m, 0.0, 1.0, low_open=True):
            out.append(("cell_m", "0 < cell_m <= 1 m"))
        if not 0 <= self.min_confidence <= 255:
            out.append(("min_confidence", "0 to 255"))
        if not 0 <= self.outlier_min_points <= 9:
            out.append(("outlier_min_points", "0 (off) to 9 points of a 3 x 3 neighbourhood"))
        if not number_in(self.max_elevation_deg, 0.0, 90.0):
            out.append(("max_elevation_deg", "0 to 90 degrees"))
        if not number_in(self.max_orientation_age_ms, 0.0, 10_000.0, low_open=True):
            out.append(("max_orientation_age_ms", "0 < max_orientation_age_ms <= 10000 ms"))
        return out


@dataclass
class ModelConfig:
    path: str = ""  # empty: the bundled model
    device: str = "auto"  # auto | cpu | cuda

    def problems(self) -> Problems:
        return one_of("device", self.device, ("auto", "cpu", "cuda"))


@dataclass
class FusionConfig:
    method: str = "hmm+voting"  # the live session's fusion (inference.fusion.METHODS)
    window: int = 5  # l_w, smoothing window (frames)
    vote_delay: int = 1  # l_v, voting half-window (frames)
    transition: list[list[float]] = field(default_factory=lambda: PAPER_TRANSITION.tolist())
    stay: float = STEADY_STAY  # "steady": per-frame stay probability
    evidence: float = STEADY_EVIDENCE  # "steady": exponent of each frame's probabilities
    hysteresis: float = HYSTERESIS  # "steady+hysteresis": posterior a switch needs

    def problems(self) -> Problems:
        out = one_of("method", self.method, METHODS)
        if not number_in(self.stay, 0.2, 1.0, low_open=True) or self.stay >= 1.0:
            out.append(("stay", "0.2 < stay < 1 (a mode must be left more rarely than kept)"))
        if not number_in(self.evidence, 0.0, 1.0, low_open=True):
            out.append(("evidence", "0 < evidence <= 1"))
        if not number_in(self.hysteresis, 0.0, 1.0) or self.hysteresis >= 1.0:
            out.append(("hysteresis", "0 <= hysteresis < 1"))
        if not 1 <= self.window <= 1000:
            out.append(("window", "1 to 1000 frames"))
        if not 0 <= self.vote_delay <= 1000:
            out.append(("vote_delay", "0 to 1000 frames"))
        rows = self.transition
        shape_ok = len(rows) == N_MODES and all(len(r) == N_MODES for r in rows)
        values_ok = shape_ok and all(math.isfinite(v) and v >= 0 for r in rows for v in r)
        if not (values_ok and all(sum(r) > 0 for r in rows)):
            out.append(
                (
                    "transition",
                    f"{N_MODES} rows of {N_MODES} finite, non-negative numbers, "
                    "each row with a positive sum",
                )
            )
        return out


# One line per key for `walkcap config` (capture.config.documented); every field has one.
DOCS: dict[type, dict[str, str]] = {
    PreprocessConfig: {
        "corridor_width_m": "width of the walking corridor kept, across the direction, metres",
        "min_forward_m": "nearest point kept ahead of the camera, metres",
        "max_forward_m": "farthest point kept ahead of the camera, metres",
        "grid_size": "the CNN's image is grid_size x grid_size cells",
        "cell_m": "cell size of the image, metres",
        "min_confidence": "lowest camera confidence a point needs to be used",
        "outlier_min_points": "isolated-point removal: neighbours needed in 3 x 3 cm (0: off)",
        "max_elevation_deg": "camera looking higher than this above level: no image, degrees",
        "max_orientation_age_ms": "IMU orientation older than this: stale_orientation, no "
        "image, no decision, ms",
        "backend": "point-cloud backend: numpy | open3d (same result; numpy is faster)",
    },
    ModelConfig: {
        "path": "classifier weights (.pt); empty: the bundled model",
        "device": "where the CNN runs: auto | cpu | cuda",
    },
    FusionConfig: {
        "method": "the live session's fusion: hmm+voting (the paper's), steady (switches "
        "once a terrain change) or another of eval's methods",
        "window": "HMM smoothing window l_w, frames",
        "vote_delay": "voting half-window l_v, frames (decisions lag by this many)",
        "transition": "HMM transition matrix (the paper's), rows and columns LG US DS UR DR",
        "stay": "steady: per-frame stay probability (0.987: a terrain held ~5 s at 15 fps)",
        "evidence": "steady: each frame's CNN probabilities to this power (its errors come "
        "in runs of 1.34 frames)",
        "hysteresis": "steady+hysteresis: the posterior level ground needs before the decision "
        "leaves stairs or a ramp for it (0.8: 4 to 1 against the others)",
    },
}
