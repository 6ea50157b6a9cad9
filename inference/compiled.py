"""The numba-compiled kernels of the per-frame pipeline: inference.corridor (the
preprocessing's steps) and inference.profile_fit (the terrain features' segments).

numba compiles a kernel on its first call and caches the machine code on disk (beside the
module, or in numba's cache folder where that is read-only): the first process on a
machine spends about 15-20 s compiling, each later one about 0.3 s loading, plus numba's
import. `make install` calls warm() once; the live session and replay call it before
their first frame, so that no frame pays either.
"""

from __future__ import annotations


def warm() -> None:
    """Compile, or load from the cache, every kernel the pipeline calls, as it calls them:
    one synthetic frame preprocessed (from its points and from its ranges), its cloud
    thinned and rounded as recorded and its profile's features; the refit of level ground's
    stretches, which that profile may not need, on its own."""
    import numpy as np

    from devices.simulator.synthetic import synthetic_frame
    from inference.config import PreprocessConfig
    from inference.corridor import first_in_voxel, quantized_cloud
    from inference.features import FIT_TRIM_M, terrain_features
    from inference.preprocess import preprocess, preprocess_ranges
    from inference.profile_fit import fit_points

    frame = synthetic_frame(0, 0)
    params = PreprocessConfig()
    level = np.array([1.0, 0.0, 0.0, 0.0])
    pre = preprocess(frame.xyz, frame.confidence, level, params)
    rays = frame.geometry.rays().astype(np.float32)
    ranges = np.round(np.linalg.norm(frame.xyz, axis=2) * 1000).astype(np.uint16)
    preprocess_ranges(ranges, rays, frame.confidence, level, params)
    terrain_features(pre.profile, "LG", params.max_forward_m)
    first_in_voxel(pre.cloud, np.float32(0.02))  # the recorded cloud's thinning
    quantized_cloud(pre.cloud, 2.0**-10)  # and its rounding
    pts = pre.profile.astype(np.float64)  # as features passes them: columns of a (M, 2) array
    fit_points(pts[:, 0], pts[:, 1], np.arange(len(pts)), FIT_TRIM_M)


if __name__ == "__main__":
    warm()
