"""The compiled half of inference.features: a leveled profile cut into straight segments.

The polyline of median ranges per elevation-angle bin, its cuts at range jumps,
split-and-merge and the line fits along the rays, as inference.features describes them and
as its straightforward numpy functions compute them (`_polyline_runs`, `_split`,
`_fit_line`, `_merge`: the reference this is tested against), compiled over the profile
grouped by angle bin, instead of a few hundred small numpy calls. Each segment's order
statistics (the median height, the 2nd, 50th and 98th percentile of its forward
distances) are worked out here too, by numpy's rules.

Compiled by numba on first use and cached beside this file (or in numba's cache folder
where this one is read-only), so that a process pays only the cache's loading. The
constants come in as arguments: a cached function keeps the values it was compiled with.
Sums and products run in loop order, where numpy's pairwise sums and BLAS may round
differently in the last bits.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# Columns of the segment table `segments()` returns, one row a segment, near to far.
FIRST, STOP = 0, 1  # the slice of the sorted profile the segment was fitted on
START_X, START_Z, END_X, END_Z = 2, 3, 4, 5  # its near and far ends on the line
ANGLE = 6  # degrees, of the travel direction near -> far: +90 a riser up, 0 flat
CENTRE_X, CENTRE_Z = 7, 8
RMS = 9  # RMS distance of its points to the line (m)
COUNT = 10  # its points: those of the slice within the trim distance of the line
LEVEL = 11  # median height of its points
X_P2, X_MEDIAN, X_P98 = 12, 13, 14  # percentiles of its points' forward distances
COLUMNS = 15


@njit(cache=True, nogil=True)
def sorted_profile(x, z, bins, cut_x):
    """The points of the profile that fit_profile keeps, in the order of their angle bins:
    the rays (bins) the forward cut crosses (a point beyond `cut_x`) left out whole, the
    rest by bin, in the profile's order within each bin. Returns x, z, bins, ranges, the
    nearest forward distance and each bin's median range (at its first point; NaN at the
    others). fit_profile's reference sorts each bin's points by range as well: the same
    points, summed in another order."""
    n = len(x)
    near = np.inf
    if n == 0:
        return x, z, bins, x.copy(), near, x.copy()
    low, high = bins.min(), bins.max()
    span = high - low + 1
    cut = np.zeros(span, np.bool_)
    for i in range(n):
        if x[i] > cut_x:
            cut[bins[i] - low] = True
    start = np.zeros(span + 1, np.int64)
    for i in range(n):
        if not cut[bins[i] - low]:
            start[bins[i] - low + 1] += 1
    for b in range(span):
        start[b + 1] += start[b]
    m = start[span]
    at = start[:span].copy()
    xs, zs, bs, rs = np.empty(m), np.empty(m), np.empty(m, np.int64), np.empty(m)
    for i in range(n):
        b = bins[i] - low
        if not cut[b]:
            k = at[b]
            at[b] += 1
            xs[k], zs[k], bs[k] = x[i], z[i], bins[i]
            rs[k] = math.sqrt(x[i] * x[i] + z[i] * z[i])
            near = min(near, x[i])
    # each bin's median range: the middle of its ranges (< 100 m) in order
    medians = np.full(m, np.nan)
    buffer = np.empty(max(m, 1))
    for b in range(span):
        first, stop = start[b], start[b + 1]
        count = stop - first
        if count:
            values = buffer[:count]
            values[:] = rs[first:stop]
            hi = _select(values, 0, count, count // 2)
            lo = hi if count % 2 else _largest(values, 0, count // 2)
            medians[first] = 0.5 * (lo + hi)  # as _polyline_runs: not _median's / 2.0
    return xs, zs, bs, rs, near, medians


@njit(cache=True, nogil=True)
def _select(a, lo, hi, k):
    """The k-th smallest of a[lo:hi] (k counted from lo), put in place: a[lo:lo + k] below
    it, a[lo + k + 1:hi] above (quickselect)."""
    left, right = lo, hi - 1
    target = lo + k
    while right > left:
        mid = (left + right) // 2
        # the median of three as the pivot, moved to `right`
        if a[mid] < a[left]:
            a[mid], a[left] = a[left], a[mid]
        if a[right] < a[left]:
            a[right], a[left] = a[left], a[right]
        if a[mid] < a[right]:
            a[mid], a[right] = a[right], a[mid]
        pivot = a[right]
        store = left
        for i in range(left, right):  # without a branch: the comparisons are a coin toss
            v = a[i]
            a[i] = a[store]
            a[store] = v
            store += v < pivot
        a[store], a[right] = a[right], a[store]
        if store == target:
            break
        if store < target:
            left = store + 1
        else:
            right = store - 1
    return a[target]


@njit(cache=True, nogil=True)
def _largest(a, lo, hi):
    top = a[lo]
    for i in range(lo + 1, hi):
        top = max(top, a[i])
    return top


@njit(cache=True, nogil=True)
def _smallest(a, lo, hi):
    low = a[lo]
    for i in range(lo + 1, hi):
        low = min(low, a[i])
    return low


@njit(cache=True, nogil=True)
def _line(sxx, sxz, szz, bx, bz, x, z, idx, n):
    """Unit normal (a, b) and offset d of the line n . p = d through the points idx[:n],
    fitted along the rays from their sums (inference.features._ray_line)."""
    det = sxx * szz - sxz * sxz
    if det > 1e-9 * (sxx + szz) ** 2:
        a = (szz * bx - sxz * bz) / det
        b = (sxx * bz - sxz * bx) / det
        norm = math.hypot(a, b)
        if norm > 0 and 1.0 / norm > 0.01:
            return a / norm, b / norm, 1.0 / norm
    # the perpendicular fit: the principal axes of the centred points
    cx, cz = bx / n, bz / n
    pxx = pxz = pzz = 0.0
    for k in range(n):
        i = idx[k]
        dx, dz = x[i] - cx, z[i] - cz
        pxx += dx * dx
        pxz += dx * dz
        pzz += dz * dz
    theta = 0.5 * math.atan2(2.0 * pxz, pxx - pzz)
    c, s = math.cos(theta), math.sin(theta)
    return -s, c, cx * -s + cz * c


@njit(cache=True, nogil=True)
def _fit(x, z, first, stop, trim, idx, out, min_count):
    """The line through the points first..stop-1 (inference.features._fit_points: fitted,
    the points beyond `trim` of it left out, fitted once more): their indices left in
    idx[:count]; into `out` the row of the segment table from START_X to COUNT. Returns
    count, or 0 when no line is fitted or fewer than `min_count` points stay its own."""
    n = stop - first
    if n < 5:
        return 0
    sxx = sxz = szz = bx = bz = 0.0
    for k in range(n):
        i = first + k
        idx[k] = i
        xi, zi = x[i], z[i]
        sxx += xi * xi
        sxz += xi * zi
        szz += zi * zi
        bx += xi
        bz += zi
    rss = 0.0
    lo = hi = 0.0
    a = b = d = cx = cz = 0.0
    for _ in range(2):
        a, b, d = _line(sxx, sxz, szz, bx, bz, x, z, idx, n)
        # the centre of the points on the line, and their extent along it: as the last
        # pass finds them when it keeps every point
        cx, cz = bx / n, bz / n
        off = cx * a + cz * b - d
        cx, cz = cx - off * a, cz - off * b
        sxx = sxz = szz = bx = bz = 0.0  # the sums of the points kept
        rss = 0.0
        lo, hi = np.inf, -np.inf
        kept = 0
        for k in range(n):
            i = idx[k]
            xi, zi = x[i], z[i]
            dist = xi * a + zi * b - d
            if abs(dist) <= trim:
                idx[kept] = i
                kept += 1
                rss += dist * dist
                sxx += xi * xi
                sxz += xi * zi
                szz += zi * zi
                bx += xi
                bz += zi
                along = (xi - cx) * -b + (zi - cz) * a
                lo = min(lo, along)
                hi = max(hi, along)
        if kept < min_count or kept == 0:
            return 0  # a second pass keeps no more than the first
        if kept == n:
            break
        n = kept
        if _ < 1 and n < 5:
            return 0
    else:  # the second pass left points out: the centre and extent of those it kept
        cx, cz = bx / n, bz / n
        off = cx * a + cz * b - d
        cx, cz = cx - off * a, cz - off * b
        lo, hi = np.inf, -np.inf
        for k in range(n):
            i = idx[k]
            along = (x[i] - cx) * -b + (z[i] - cz) * a
            lo = min(lo, along)
            hi = max(hi, along)
    ux, uz = -b, a  # the line's direction
    x0, z0 = cx + lo * ux, cz + lo * uz
    x1, z1 = cx + hi * ux, cz + hi * uz
    if math.atan2(z0, x0) > math.atan2(z1, x1):  # near to far: up the elevation angle
        x0, z0, x1, z1 = x1, z1, x0, z0
    out[START_X], out[START_Z], out[END_X], out[END_Z] = x0, z0, x1, z1
    out[ANGLE] = math.degrees(math.atan2(z1 - z0, x1 - x0))
    out[CENTRE_X], out[CENTRE_Z] = cx, cz
    out[RMS] = math.sqrt(rss / n)
    out[COUNT] = n
    return n


@njit(cache=True, nogil=True)
def _percentile(values, n, q):
    """numpy.percentile(values[:n], q) by its linear rule, rounding alike, for q < 50
    (> 50: of -values, negated): the few values beyond it kept in order in one pass."""
    low = q < 50.0
    virtual = (n - 1) * (q / 100.0)
    if virtual >= n - 1:
        return _largest(values, 0, n)
    below = math.floor(virtual)
    i = int(below)
    # the order statistics i and i + 1 from the near end: the first `keep` in order
    rank = i if low else n - 2 - i
    keep = rank + 2
    best = np.empty(keep)
    count = 0
    for k in range(n):  # the far end first: a segment's points come near to far, mostly
        v = values[k] if low else -values[n - 1 - k]
        if count == keep and not v < best[keep - 1]:
            continue
        j = min(count, keep - 1)
        while j > 0 and best[j - 1] > v:
            best[j] = best[j - 1]
            j -= 1
        best[j] = v
        count = min(count + 1, keep)
    a, b = (best[rank], best[rank + 1]) if low else (-best[rank + 1], -best[rank])
    gamma = virtual - below
    diff = b - a
    return b - diff * (1.0 - gamma) if gamma >= 0.5 else a + diff * gamma


@njit(cache=True, nogil=True)
def _median(values, n):
    """numpy.median(values[:n]) (the values reordered)."""
    hi = _select(values, 0, n, n // 2)
    return hi if n % 2 else (_largest(values, 0, n // 2) + hi) / 2.0


@njit(cache=True, nogil=True)
def _order_statistics(x, z, idx, n, row):
    values = np.empty(n)
    for k in range(n):
        values[k] = z[idx[k]]
    row[LEVEL] = _median(values, n)
    for k in range(n):
        values[k] = x[idx[k]]
    row[X_P2] = _percentile(values, n, 2.0)
    row[X_P98] = _percentile(values, n, 98.0)
    row[X_MEDIAN] = _median(values, n)


@njit(cache=True, nogil=True)
def _jumps(step, break_gap, ratio, window):
    """inference.features._jumps: steps longer than break_gap and ratio times the median of
    the `window` steps either side (the ends padded with the end steps)."""
    m = len(step)
    out = np.zeros(m, np.bool_)
    around = np.empty(2 * window)
    for i in range(m):
        if not step[i] > break_gap:
            continue
        k = 0
        for j in range(i - window, i + window + 1):
            if j != i:
                around[k] = step[min(max(j, 0), m - 1)]
                k += 1
        around.sort()
        median = (around[window - 1] + around[window]) / 2.0
        out[i] = step[i] > ratio * median
    return out


@njit(cache=True, nogil=True)
def _polyline(bins, medians, bin_rad, min_bin_points, break_gap, jump_ratio, jump_window):
    """inference.features._polyline_runs: the vertices (x, z, own bin) and where each run
    of at least 3 begins and ends (run_lo, run_hi: vertex indices, inclusive). `medians`:
    each bin's median range, at its first point."""
    n = len(bins)
    vx = np.empty(n)
    vz = np.empty(n)
    own = np.empty(n, np.int64)
    v = 0
    s = 0
    while s < n:
        e = s + 1
        while e < n and bins[e] == bins[s]:
            e += 1
        count = e - s
        if count >= min_bin_points:
            r = medians[s]
            centre = (bins[s] + 0.5) * bin_rad
            vx[v] = r * math.cos(centre)
            vz[v] = r * math.sin(centre)
            own[v] = bins[s]
            v += 1
        s = e
    run_lo = np.empty(v, np.int64)
    run_hi = np.empty(v, np.int64)
    runs = 0
    if v < 2:
        return vx[:v], vz[:v], own[:v], run_lo[:0], run_hi[:0]
    step = np.empty(v - 1)
    for i in range(v - 1):
        step[i] = math.hypot(vx[i + 1] - vx[i], vz[i + 1] - vz[i])
    jumps = _jumps(step, break_gap, jump_ratio, jump_window)
    lo = 0
    for i in range(v):
        if i == v - 1 or jumps[i] or own[i + 1] - own[i] > 3:
            if i - lo + 1 >= 3:
                run_lo[runs] = lo
                run_hi[runs] = i
                runs += 1
            lo = i + 1
    return vx[:v], vz[:v], own[:v], run_lo[:runs], run_hi[:runs]


@njit(cache=True, nogil=True)
def _split(vx, vz, lo, hi, tol):
    """inference.features._split (Douglas-Peucker) on vertices lo..hi: the pieces in
    order, as (first vertex, last vertex) rows."""
    pieces = np.empty((hi - lo + 1, 2), np.int64)
    count = 0
    stack = np.empty((hi - lo + 1, 2), np.int64)
    top = 0
    stack[0, 0], stack[0, 1] = lo, hi
    top = 1
    while top:
        top -= 1
        a, b = stack[top, 0], stack[top, 1]
        cut = -1
        if b - a >= 2:
            dx, dz = vx[b] - vx[a], vz[b] - vz[a]
            norm = max(math.hypot(dx, dz), 1e-9)
            best = -1.0
            for k in range(a + 1, b):
                dist = abs((vx[k] - vx[a]) * dz - (vz[k] - vz[a]) * dx) / norm
                if dist > best:  # the first of equal distances, as argmax
                    best, cut = dist, k
            if not best > tol:
                cut = -1
        if cut < 0:
            pieces[count, 0], pieces[count, 1] = a, b
            count += 1
        else:  # the far half waits: pieces come out near to far
            stack[top, 0], stack[top, 1] = cut, b
            stack[top + 1, 0], stack[top + 1, 1] = a, cut
            top += 2
    return pieces[:count]


@njit(cache=True, nogil=True)
def segments(
    x,
    z,
    bins,
    medians,
    bin_rad,
    min_bin_points,
    break_gap,
    jump_ratio,
    jump_window,
    split_tol,
    trim,
    merge_ratio,
    merge_kept,
):
    """The segments of a profile as sorted_profile() returns it (its bins' median ranges
    in `medians`): the segment table (one row a segment, the columns above) and its
    points' indices, segment after segment (row r's are COUNT of them, after those of the
    rows before)."""
    n = len(x)
    vx, vz, own, run_lo, run_hi = _polyline(
        bins, medians, bin_rad, min_bin_points, break_gap, jump_ratio, jump_window
    )
    idx = np.empty(n, np.int64)
    row = np.empty(COLUMNS)
    table = np.empty((max(len(vx), 1), COLUMNS))
    total = 0
    for r in range(len(run_lo)):
        pieces = _split(vx, vz, run_lo[r], run_hi[r], split_tol)
        # the fitted pieces: first vertex, last vertex and their table rows
        k = len(pieces)
        lo = np.empty(k, np.int64)
        hi = np.empty(k, np.int64)
        fits = np.empty((k, COLUMNS))
        m = 0
        for p in range(k):
            a, b = pieces[p, 0], pieces[p, 1]
            if b - a < 2:  # two vertices say nothing about a surface
                continue
            first = np.searchsorted(bins, own[a])
            stop = np.searchsorted(bins, own[b] + 1)
            if _fit(x, z, first, stop, trim, idx, row, 0):
                lo[m], hi[m] = a, b
                fits[m] = row
                fits[m, FIRST], fits[m, STOP] = first, stop
                m += 1
        # the merge: the best pair of neighbours one line explains as well, first
        pair = np.empty((max(m, 1), COLUMNS))  # the fit of row i with row i + 1
        known = np.zeros(max(m, 1), np.bool_)
        while m > 1:
            best, best_ratio = -1, merge_ratio
            for i in range(m - 1):
                if hi[i] != lo[i + 1]:
                    continue
                if not known[i]:
                    first, stop = int(fits[i, FIRST]), int(fits[i + 1, STOP])
                    least = merge_kept * (fits[i, COUNT] + fits[i + 1, COUNT])
                    if _fit(x, z, first, stop, trim, idx, row, least):
                        pair[i] = row
                        pair[i, FIRST], pair[i, STOP] = first, stop
                    else:
                        pair[i, COUNT] = -1.0
                    known[i] = True
                if pair[i, COUNT] < 0 or pair[i, COUNT] < merge_kept * (
                    fits[i, COUNT] + fits[i + 1, COUNT]
                ):
                    continue
                rss_a = fits[i, RMS] ** 2 * fits[i, COUNT]
                rss_b = fits[i + 1, RMS] ** 2 * fits[i + 1, COUNT]
                ratio = pair[i, RMS] ** 2 * pair[i, COUNT] / max(rss_a + rss_b, 1e-12)
                if ratio <= best_ratio:
                    best, best_ratio = i, ratio
            if best < 0:
                break
            fits[best] = pair[best]
            hi[best] = hi[best + 1]
            for i in range(best + 1, m - 1):
                lo[i], hi[i] = lo[i + 1], hi[i + 1]
                fits[i] = fits[i + 1]
                pair[i] = pair[i + 1]
                known[i] = known[i + 1]
            m -= 1
            known[best] = False
            if best > 0:
                known[best - 1] = False
        if total + m > len(table):
            grown = np.empty((2 * (total + m), COLUMNS))
            grown[:total] = table[:total]
            table = grown
        table[total : total + m] = fits[:m]
        total += m
    # each segment's points, and their order statistics
    members = np.empty(n, np.int64)
    at = 0
    for s in range(total):
        count = _fit(x, z, int(table[s, FIRST]), int(table[s, STOP]), trim, idx, row, 0)
        if at + count > len(members):
            grown_members = np.empty(2 * (at + count), np.int64)
            grown_members[:at] = members[:at]
            members = grown_members
        members[at : at + count] = idx[:count]
        _order_statistics(x, z, idx, count, table[s])
        at += count
    return table[:total], members[:at]


@njit(cache=True, nogil=True)
def fit_points(x, z, index, trim):
    """inference.features._fit_points on the points `index` (increasing): the table row
    (FIRST and STOP unset) and the indices kept, or an empty row set when no line fits."""
    n = len(index)
    idx = np.empty(max(n, 1), np.int64)
    row = np.zeros(COLUMNS)
    # _fit takes a slice; a compact copy of the chosen points makes one
    cx = x[index]
    cz = z[index]
    count = _fit(cx, cz, 0, n, trim, idx, row, 0)
    if not count:
        return np.empty((0, COLUMNS)), idx[:0]
    kept = index[idx[:count]]
    _order_statistics(cx, cz, idx, count, row)
    return row.reshape(1, COLUMNS), kept
