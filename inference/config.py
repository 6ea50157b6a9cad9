"""The algorithms' configuration sections: [preprocess], [model], [fusion].

capture.config composes every package's sections into the one TOML file and validates
each key by the type of its field here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from inference.fusion import PAPER_TRANSITION  # the authors' matrix, defined once


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
    backend: str = "numpy"  # numpy | open3d (same result; numpy is faster)


@dataclass
class ModelConfig:
    path: str = ""  # empty: the bundled model
    device: str = "auto"  # auto | cpu | cuda


@dataclass
class FusionConfig:
    window: int = 5  # l_w, smoothing window (frames)
    vote_delay: int = 1  # l_v, voting half-window (frames)
    transition: list[list[float]] = field(default_factory=lambda: PAPER_TRANSITION.tolist())


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
        "backend": "point-cloud backend: numpy | open3d (same result; numpy is faster)",
    },
    ModelConfig: {
        "path": "classifier weights (.pt); empty: the bundled model",
        "device": "where the CNN runs: auto | cpu | cuda",
    },
    FusionConfig: {
        "window": "HMM smoothing window l_w, frames",
        "vote_delay": "voting half-window l_v, frames (decisions lag by this many)",
        "transition": "HMM transition matrix (the paper's), rows and columns LG US DS UR DR",
    },
}
