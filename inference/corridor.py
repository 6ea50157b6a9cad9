"""The compiled steps of inference.preprocess: points from ranges, the corridor's points,
the isolated ones removed, the binary image.

Each step gives what the straightforward numpy functions of inference.preprocess give,
bit for bit: the same float32 operations in the same order (numpy compares a float32
array with a threshold cast to float32, and so do these, given float32 thresholds). The
dot products that level the points stay with numpy (its BLAS rounds as it does), between
these steps. Compiled by numba on first use and cached, as inference.profile_fit.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def points_from_ranges(mm, rays):
    """(H * W, 3) float32 camera-frame points in metres from (H, W) ranges in mm and
    (H, W, 3) float32 unit rays (capture.recording.topics.xyz_from_range, flattened)."""
    h, w = mm.shape
    out = np.empty((h * w, 3), np.float32)
    scale = np.float32(0.001)
    for r in range(h):
        for c in range(w):
            metres = np.float32(mm[r, c]) * scale
            k = r * w + c
            out[k, 0] = metres * rays[r, c, 0]
            out[k, 1] = metres * rays[r, c, 1]
            out[k, 2] = metres * rays[r, c, 2]
    return out


@njit(cache=True, nogil=True)
def corridor_indices(y, confidence, half, min_confidence):
    """The indices of the points within `half` of the corridor's centre line (y: their
    lateral coordinate) and of at least `min_confidence`, in order."""
    n = len(y)
    out = np.empty(n + 1, np.int64)
    k = 0
    for i in range(n):  # without a branch: every index written, the kept ones advance
        out[k] = i
        k += (abs(y[i]) <= half) & (confidence[i] >= min_confidence)
    return out[:k]


@njit(cache=True, nogil=True)
def gather(flat, index):
    """flat[index] for (N, 3) points."""
    out = np.empty((len(index), 3), flat.dtype)
    for k in range(len(index)):
        i = index[k]
        out[k, 0], out[k, 1], out[k, 2] = flat[i, 0], flat[i, 1], flat[i, 2]
    return out


@njit(cache=True, nogil=True)
def corridor_cloud(
    x, y, z, keep, min_forward, max_forward, min_height, max_height, cell, min_points
):
    """The leveled cloud (N, 3) of the corridor's points (x forward and z up of each, y
    lateral of every point, `keep` the corridor's indices into y) inside the box, without
    those whose 3 x 3 sagittal cells of `cell` (a float32 1 / cell size) hold fewer than
    `min_points` points (min_points <= 1: every point kept)."""
    n = len(x)
    cloud = np.empty((n, 3), np.float32)
    m = 0
    for k in range(n):
        xk, zk = x[k], z[k]
        if xk >= min_forward and xk <= max_forward and zk >= min_height and zk <= max_height:
            cloud[m, 0], cloud[m, 1], cloud[m, 2] = xk, y[keep[k]], zk
            m += 1
    cloud = cloud[:m]
    if min_points <= 1 or m == 0:
        return cloud
    x_min, z_min = cloud[0, 0], cloud[0, 2]
    for k in range(m):
        x_min = min(x_min, cloud[k, 0])
        z_min = min(z_min, cloud[k, 2])
    ix = np.empty(m, np.int32)
    iz = np.empty(m, np.int32)
    width = height = 0
    for k in range(m):  # one empty cell around
        ix[k] = np.int32((cloud[k, 0] - x_min) * cell) + 1
        iz[k] = np.int32((cloud[k, 2] - z_min) * cell) + 1
        width = max(width, ix[k] + 2)
        height = max(height, iz[k] + 2)
    counts = np.zeros((height, width), np.int32)
    for k in range(m):
        counts[iz[k], ix[k]] += 1
    dense = np.empty((m, 3), np.float32)
    kept = 0
    for k in range(m):
        r, c = iz[k], ix[k]
        box = 0
        for dr in range(-1, 2):
            for dc in range(-1, 2):
                box += counts[r + dr, c + dc]
        if box >= min_points:
            dense[kept] = cloud[k]
            kept += 1
    return dense[:kept]


@njit(cache=True, nogil=True)
def rasterise(profile, grid, cell):
    """inference.preprocess.rasterise of float32 (N, 2) points with `cell` a float32
    1 / cell size: the image, and the minimum x and (of the points the x crop kept) z."""
    image = np.zeros((grid, grid), np.uint8)
    n = len(profile)
    x_min = profile[0, 0]
    for k in range(n):
        x_min = min(x_min, profile[k, 0])
    col = np.empty(n, np.int32)
    z_min = np.float32(np.inf)
    for k in range(n):
        col[k] = np.int32((profile[k, 0] - x_min) * cell) + 1
        if col[k] < grid:
            z_min = min(z_min, profile[k, 1])
    for k in range(n):
        if col[k] < grid:
            up = np.int32((profile[k, 1] - z_min) * cell) + 1
            if up < grid:
                image[grid - 1 - up, col[k]] = 1
    return image, x_min, z_min


@njit(cache=True, nogil=True)
def first_in_voxel(points, voxel):
    """The indices of the first of the (N, 3) float32 points in each voxel of `voxel`
    (float32) metres, in order: capture.recording.encode.thin_cloud's np.unique of the
    voxels' keys, first occurrences, in the points' order (a hash table of the keys)."""
    n = len(points)
    bits = 1
    while (1 << bits) < 2 * n:
        bits += 1
    size = 1 << bits
    shift = np.uint64(64 - bits)  # a slot: the top bits of the key times a golden-ratio odd
    table = np.full(size, -1, np.int64)  # keys are >= 0: the cells are offset by 2^20
    out = np.empty(n, np.int64)
    k = 0
    offset = np.int64(1 << 20)
    for i in range(n):
        cx = np.int64(np.floor(points[i, 0] / voxel)) + offset
        cy = np.int64(np.floor(points[i, 1] / voxel)) + offset
        cz = np.int64(np.floor(points[i, 2] / voxel)) + offset
        key = (cx << 42) | (cy << 21) | cz
        slot = np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> shift)
        while table[slot] != -1 and table[slot] != key:
            slot = (slot + 1) & (size - 1)
        if table[slot] == -1:
            table[slot] = key
            out[k] = i
            k += 1
    return out[:k]


@njit(cache=True, nogil=True)
def quantized_cloud(cloud, quantum):
    """The (N, 3) points as capture.recording.topics.cloud_message records them: the finite
    ones, sorted by x (stable), each coordinate rounded to a multiple of `quantum` in
    float64, as float32."""
    n = len(cloud)
    finite = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        if np.isfinite(cloud[i, 0]) and np.isfinite(cloud[i, 1]) and np.isfinite(cloud[i, 2]):
            finite[m] = i
            m += 1
    x = np.empty(m)
    for k in range(m):
        x[k] = np.float64(cloud[finite[k], 0])
    order = np.argsort(x, kind="mergesort")
    out = np.empty((m, 3), np.float32)
    for k in range(m):
        i = finite[order[k]]
        for c in range(3):
            out[k, c] = np.float32(np.rint(np.float64(cloud[i, c]) / quantum) * quantum)
    return out
