"""A hierarchical spatial hash of axis-aligned boxes: all overlapping pairs, and box queries (numba).

Every box goes to the level where it covers at most 2 x 2 x 2 cells (cells
double per level, level 0 has cells of size ``1 / inv``), so large and small
elements cost the same. Each level has its own hash table, sized to what it
holds: the coarse levels, where few long elements live, stay small and in
cache. Every slot (an element in one cell) keeps a copy of its element's box
and the packed coordinates of its cell, so a scan reads its bucket in order
and hash collisions are told apart without looking anything up; the slots of
a bucket are sorted by the boxes' lower x, and a scan stops at the first box
that starts beyond the one it tests. The tests of a candidate are combined
without branches: about a third of the candidates overlap, so branches on
them would mostly be mispredicted.

Overlapping pairs on one level are enumerated without queries: two such
elements meet in a cell they share, so the pairs inside every bucket are tried (the
buckets are contiguous: this is a scan of memory in order); a pair on two
levels is found by looking up, for every element of one of them, the cells
its box covers on the other (from the finer level, or from the coarser when
its elements are so few that their many fine cells cost less). A pair is
reported once, from the cell (on the level looked up) holding the lower
corner of the intersection of the boxes.

libigl's AABB tree and scipy's cKDTree answer point queries; the moving
surfaces of the refinement need all pairs of overlapping swept boxes of
hundreds of thousands of elements every iteration, which this does in one
pass over the buckets.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from fracture.mesh import morton
from fracture.tolerances import tol

_BITS = 21  # bits per packed cell coordinate
_OFF = 1 << (_BITS - 1)
_SPAN = float(1 << (_BITS - 2))  # boxes span at most this many level-0 cells (see cell_size)


class HashGrid(NamedTuple):
    """A built grid (:func:`build`): per level the inverse cell size (``scale``); each element's
    ``level``; per level the offset of its table in ``start`` (``toff``) and its mask (``tmask``:
    tables are powers of two, ``-1`` for an empty level); the buckets as CSR ranges
    ``start[b]:start[b + 1]`` of slots; per slot its element (``items``), its cell's packed
    coordinates (``key``) and its element's box (``box``: lower then upper corner)."""

    scale: np.ndarray
    level: np.ndarray
    toff: np.ndarray
    tmask: np.ndarray
    start: np.ndarray
    items: np.ndarray
    key: np.ndarray
    box: np.ndarray


@numba.njit(cache=True, inline="always")
def _hash(ix, iy, iz, mask):
    """The cell's Morton code, cut to the table: cells near each other share cache lines
    (the elements come in Morton order too, see :func:`~fracture.refine.order.spatial_order`)."""
    return morton.code(ix, iy, iz) & mask


@numba.njit(cache=True, inline="always")
def _key(ix, iy, iz):
    return ((ix + _OFF) << (2 * _BITS)) | ((iy + _OFF) << _BITS) | (iz + _OFF)


@numba.njit(cache=True, inline="always")
def _key_x(key):
    """The x cell coordinate that :func:`_key` packed into ``key``."""
    return (key >> (2 * _BITS)) - _OFF


@numba.njit(cache=True, inline="always")
def _cell(x, s):
    return np.int64(np.floor(x * s))


@numba.njit(cache=True)
def _level(lo, hi, inv):
    """The level at which a box spans at most two cells per axis."""
    extent = max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) * inv
    level = 0
    while extent > 1.0 and level < 40:
        extent *= 0.5
        level += 1
    return level


@numba.njit(cache=True)
def _scales(inv, levels):
    """``inv / 2^L`` for every level (a power is slow inside the loops)."""
    s = np.empty(levels)
    s[0] = inv
    for L in range(1, levels):
        s[L] = 0.5 * s[L - 1]
    return s


@numba.njit(cache=True)
def build(lo, hi, inv):
    """Hash the boxes ``lo, hi (k, 3)`` of ``k`` elements.

    Returns the :class:`HashGrid`.
    """
    k = lo.shape[0]
    level = np.empty(k, np.int64)
    per_level = np.zeros(41, np.int64)
    scale = _scales(inv, 41)
    cells = np.empty(k, np.int64)  # per element, the cells its box covers
    for e in range(k):
        level[e] = L = _level(lo[e], hi[e], inv)
        s = scale[L]
        cells[e] = ((_cell(hi[e, 0], s) - _cell(lo[e, 0], s) + 1) * (_cell(hi[e, 1], s) - _cell(lo[e, 1], s) + 1)
                    * (_cell(hi[e, 2], s) - _cell(lo[e, 2], s) + 1))
        per_level[L] += cells[e]
    top = 0
    for L in range(41):
        if per_level[L]:
            top = L
    toff = np.zeros(top + 2, np.int64)
    tmask = np.full(top + 1, -1, np.int64)
    for L in range(top + 1):
        size = 0
        if per_level[L]:
            size = 16
            while 2 * size < per_level[L]:
                size *= 2
            tmask[L] = size - 1
        toff[L + 1] = toff[L] + size
    # every element's cells, listed once in element order (bucket and packed
    # coordinates), then moved into their buckets (a counting sort)
    slots = per_level.sum()
    cell_bucket = np.empty(slots, np.int64)
    cell_key = np.empty(slots, np.int64)
    start = np.zeros(toff[-1] + 1, np.int64)
    p = 0
    for e in range(k):
        L = level[e]
        s = scale[L]
        for ix in range(_cell(lo[e, 0], s), _cell(hi[e, 0], s) + 1):
            for iy in range(_cell(lo[e, 1], s), _cell(hi[e, 1], s) + 1):
                for iz in range(_cell(lo[e, 2], s), _cell(hi[e, 2], s) + 1):
                    cell_bucket[p] = b = toff[L] + _hash(ix, iy, iz, tmask[L])
                    cell_key[p] = _key(ix, iy, iz)
                    start[b + 1] += 1
                    p += 1
    for b in range(toff[-1]):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    items = np.empty(slots, np.int64)
    key = np.empty(slots, np.int64)
    p = 0
    for e in range(k):
        for _ in range(cells[e]):
            q = fill[cell_bucket[p]]
            fill[cell_bucket[p]] += 1
            items[q], key[q] = e, cell_key[p]
            p += 1
    # every bucket sorted by the boxes' lower x: scans of a bucket stop at the
    # first box that starts beyond theirs
    _sort_buckets(lo, scale, toff, start, items, key)
    box = np.empty((slots, 6))
    for p in range(slots):
        e = items[p]
        for c in range(3):
            box[p, c] = lo[e, c]
            box[p, 3 + c] = hi[e, c]
    return HashGrid(scale[: top + 1], level, toff, tmask, start, items, key, box)


@numba.njit(cache=True)
def _sort_buckets(lo, scale, toff, start, items, key):
    """Sort the slots of every bucket by their boxes' lower x (stably within a cell).

    A box on level L that covers cell ``ix`` starts within a cell of it
    (``lo * s`` in ``[ix - 1, ix + 1)``): a counting sort on 2n sub-cells of
    that span puts a bucket of n slots almost in order, and an insertion sort
    finishes. (An insertion sort alone moves a slot past a quarter of its
    bucket on average.)
    """
    n_max = 0
    for b in range(toff[-1]):
        n_max = max(n_max, start[b + 1] - start[b])
    x = np.empty(n_max)
    sub = np.empty(n_max, np.int64)
    count = np.empty(2 * n_max + 1, np.int64)
    t_items = np.empty(n_max, np.int64)
    t_key = np.empty(n_max, np.int64)
    t_x = np.empty(n_max)
    for L in range(toff.shape[0] - 1):
        s = scale[L]
        for b in range(toff[L], toff[L + 1]):
            s0 = start[b]
            n = start[b + 1] - s0
            for i in range(n):
                x[i] = lo[items[s0 + i], 0]
            if n > 8:
                count[: 2 * n + 1] = 0
                for i in range(n):
                    u = (x[i] * s - _key_x(key[s0 + i]) + 1.0) * n
                    sub[i] = j = min(np.int64(u) if u > 0.0 else 0, 2 * n - 1)
                    count[j + 1] += 1
                for j in range(2 * n):
                    count[j + 1] += count[j]
                for i in range(n):
                    q = count[sub[i]]
                    count[sub[i]] = q + 1
                    t_items[q], t_key[q], t_x[q] = items[s0 + i], key[s0 + i], x[i]
                for i in range(n):
                    items[s0 + i], key[s0 + i], x[i] = t_items[i], t_key[i], t_x[i]
            for i in range(1, n):
                e, c, xi = items[s0 + i], key[s0 + i], x[i]
                q = i - 1
                while q >= 0 and x[q] > xi:
                    items[s0 + q + 1], key[s0 + q + 1], x[q + 1] = items[s0 + q], key[s0 + q], x[q]
                    q -= 1
                items[s0 + q + 1], key[s0 + q + 1], x[q + 1] = e, c, xi


@numba.njit(cache=True, inline="always")
def _overlap(box, p, lo, hi):
    return ((lo[0] <= box[p, 3]) & (box[p, 0] <= hi[0]) & (lo[1] <= box[p, 4]) & (box[p, 1] <= hi[1])
            & (lo[2] <= box[p, 5]) & (box[p, 2] <= hi[2]))


@numba.njit(cache=True, inline="always")
def _corner_key(box, p, q, s):
    """Packed cell (at scale ``s``) of the lower corner of the intersection of the boxes of slots p and q."""
    return _key(_cell(max(box[p, 0], box[q, 0]), s), _cell(max(box[p, 1], box[q, 1]), s),
                _cell(max(box[p, 2], box[q, 2]), s))


@numba.njit(cache=True)
def _room(out, count, more):
    """``out`` (rows of pairs, ``count`` used), grown to hold ``more`` rows more."""
    if count + more <= out.shape[0]:
        return out
    bigger = np.empty((max(2 * out.shape[0], count + more), out.shape[1]), out.dtype)
    bigger[:count] = out[:count]
    return bigger


def pairs(grid) -> np.ndarray:
    """Every pair ``(e, g), e < g`` of elements whose boxes overlap, once, as an ``(c, 2)`` array (the
    same rows in the same order on any number of threads)."""
    return _pairs(grid, numba.get_num_threads())


@numba.njit(cache=True)
def _pairs(grid, threads):
    out, count = _pairs_on_one_level_parallel(grid, threads)
    if count < 0:  # a chunk ran out of room: the serial search grows its array as it goes
        out, count = _pairs_on_one_level(grid)
    out, count = _pairs_on_two_levels(grid, out, count, threads)
    return out[:count]


# Pairs of one level are searched in this many chunks of buckets per thread (the buckets differ in size).
_CHUNKS_PER_THREAD = 4
# Room for this many pairs per slot in a chunk of the parallel search (the refinement's grids hold 2 to 7);
# a chunk that needs more sends the search to the serial one.
_PAIRS_PER_SLOT = 8


@numba.njit(cache=True, parallel=True)
def _pairs_on_one_level_parallel(grid, threads):
    """:func:`_pairs_on_one_level` on ``threads`` threads: the buckets in contiguous chunks of about equal
    numbers of slots, each chunk's pairs into rows of its own, then the chunks' rows one after the
    other (the serial order). Returns ``count = -1`` if a chunk had not the room."""
    scale, level, toff, tmask, start, items, key, box = grid
    n_buckets = toff[-1]
    bucket_level = np.empty(n_buckets, np.int64)
    for L in range(tmask.shape[0]):
        bucket_level[toff[L]:toff[L + 1]] = L
    k = max(1, min(n_buckets, _CHUNKS_PER_THREAD * threads))
    # chunk c holds buckets first[c]:first[c + 1], of about start[-1] / k slots each
    first = np.searchsorted(start[:n_buckets], np.arange(k + 1) * (start[n_buckets] / k))
    first[0], first[k] = 0, n_buckets
    room = np.empty(k + 1, np.int64)
    room[0] = 0
    for c in range(k):
        room[c + 1] = room[c] + 1024 + _PAIRS_PER_SLOT * (start[first[c + 1]] - start[first[c]])
    rows = np.empty((room[k], 2), np.int64)
    counts = np.zeros(k, np.int64)
    for c in numba.prange(k):
        count, cap, full = room[c], room[c + 1], False
        for b in range(first[c], first[c + 1]):
            s, end = scale[bucket_level[b]], start[b + 1]
            for p in range(start[b], end):
                if count + (end - p) > cap:
                    full = True
                    break
                count = _pairs_of_slot(p, end, s, items, key, box, rows, count)
            if full:
                break
        counts[c] = -1 if full else count - room[c]
    if (counts < 0).any():
        return rows, -1
    out = np.empty((max(1024, _PAIRS_PER_SLOT * items.shape[0], counts.sum()), 2), np.int64)
    n = 0
    for c in range(k):
        out[n:n + counts[c]] = rows[room[c]:room[c] + counts[c]]
        n += counts[c]
    return out, n


@numba.njit(cache=True, inline="always")
def _pairs_of_slot(p, end, s, items, key, box, out, count):
    """The candidates of slot ``p`` among the later slots of its bucket (up to ``end``) written from row
    ``count`` of ``out``; returns the rows' count with the pairs among them (module notes)."""
    e, kp = items[p], key[p]
    # p's box in locals, and its corner cells with q's written out: writes to
    # out might alias box for the compiler, which then reloads it (20 % slower)
    x0, y0, z0, x1, y1, z1 = box[p, 0], box[p, 1], box[p, 2], box[p, 3], box[p, 4], box[p, 5]
    for q in range(p + 1, end):
        if box[q, 0] > x1:
            break
        g = items[q]
        out[count, 0] = min(e, g)
        out[count, 1] = max(e, g)
        # same cell (not a hash collision), overlapping, and reported from
        # the cell of the lower corner of the boxes' intersection
        count += ((key[q] == kp) & (y0 <= box[q, 4]) & (box[q, 1] <= y1) & (z0 <= box[q, 5])
                  & (box[q, 2] <= z1)
                  & (_key(_cell(max(x0, box[q, 0]), s), _cell(max(y0, box[q, 1]), s),
                          _cell(max(z0, box[q, 2]), s)) == kp))
    return count


@numba.njit(cache=True)
def _pairs_on_one_level(grid):
    """The pairs of elements on one level: they share a cell, so the pairs inside every bucket are
    tried; the bucket is sorted by lower x, so the scan for partners of p ends at the first box
    starting beyond p's. Every candidate is written, and counted only if it is a pair (no branches,
    see the module notes). Returns the pairs as rows of a larger array, and their number.
    """
    scale, level, toff, tmask, start, items, key, box = grid
    # room for 8 pairs per slot (the refinement's grids hold 2 to 7): growing would copy them all
    out = np.empty((max(1024, _PAIRS_PER_SLOT * items.shape[0]), 2), np.int64)
    count = 0
    for L in range(tmask.shape[0]):
        s = scale[L]
        for b in range(toff[L], toff[L + 1]):
            end = start[b + 1]
            for p in range(start[b], end):
                out = _room(out, count, end - p)
                count = _pairs_of_slot(p, end, s, items, key, box, out, count)
    return out, count


@numba.njit(cache=True, parallel=True)
def _pairs_on_two_levels(grid, out, count, threads):
    """Add to ``out`` (``count`` rows used) the pairs of elements on two levels: the elements of
    one level look up the cells their boxes cover on the other, from whichever side covers fewer
    cells (the many small elements of level 0 looking up every coarse level would mostly find
    empty buckets; the few coarse ones cover many fine cells).

    The lookups (a source slot and the level it looks up) are listed in the serial order and
    made on ``threads`` threads in contiguous chunks, each chunk's pairs into rows of its own
    (:data:`_PAIRS_PER_SLOT` per lookup); a chunk that has not the room is made again on its own
    array, which grows. The chunks' rows are then appended in order: the rows and their order do
    not depend on the number of threads."""
    items, box = grid.items, grid.box
    top = grid.tmask.shape[0] - 1
    corners = _corner_slots(grid)
    n_work = 0
    for coarse in range(1, top + 1):
        for fine in range(coarse):
            if corners[fine].shape[0] and corners[coarse].shape[0]:
                n_work += corners[coarse if look_down(corners[fine].shape[0], corners[coarse].shape[0],
                                                      coarse - fine) else fine].shape[0]
    source_slot = np.empty(n_work, np.int64)
    target_level = np.empty(n_work, np.int64)
    n_work = 0
    for coarse in range(1, top + 1):
        for fine in range(coarse):
            n_fine, n_coarse = corners[fine].shape[0], corners[coarse].shape[0]
            if not n_fine or not n_coarse:
                continue
            source, target = (coarse, fine) if look_down(n_fine, n_coarse, coarse - fine) else (fine, coarse)
            for p in corners[source]:
                source_slot[n_work], target_level[n_work] = p, target
                n_work += 1
    k = max(1, min(n_work, _CHUNKS_PER_THREAD * threads))
    first = (np.arange(k + 1) * n_work) // k
    offset = np.zeros(k + 1, np.int64)  # chunk c's rows: offset[c]:offset[c + 1]
    for c in range(k):
        offset[c + 1] = offset[c] + 1024 + _PAIRS_PER_SLOT * (first[c + 1] - first[c])
    rows = np.empty((offset[k], 2), np.int64)
    counts = np.zeros(k, np.int64)
    for c in numba.prange(k):
        buf = np.empty(256, np.int64)
        n = offset[c]
        for w in range(first[c], first[c + 1]):
            buf, m = _slots(grid, box[source_slot[w], :3], box[source_slot[w], 3:], target_level[w],
                            target_level[w] + 1, buf)
            if n + m > offset[c + 1]:
                n = -1
                break
            n = _write_pairs(items, source_slot[w], buf, m, rows, n)
        counts[c] = n - offset[c] if n >= 0 else -1
    buf = np.empty(256, np.int64)
    for c in range(k):
        if counts[c] >= 0:
            out = _room(out, count, counts[c])
            out[count:count + counts[c]] = rows[offset[c]:offset[c] + counts[c]]
            count += counts[c]
            continue
        for w in range(first[c], first[c + 1]):  # the chunk that had not the room, on the growing array
            buf, m = _slots(grid, box[source_slot[w], :3], box[source_slot[w], 3:], target_level[w],
                            target_level[w] + 1, buf)
            out = _room(out, count, m)
            count = _write_pairs(items, source_slot[w], buf, m, out, count)
    return out, count


@numba.njit(cache=True, inline="always")
def _write_pairs(items, p, found, m, out, count):
    """The pairs of slot ``p``'s element with the elements of the first ``m`` slots of ``found``, from row
    ``count`` of ``out``; returns the rows' count."""
    e = items[p]
    for i in range(m):
        g = items[found[i]]
        out[count, 0] = min(e, g)
        out[count, 1] = max(e, g)
        count += 1
    return count


@numba.njit(cache=True)
def look_down(n_fine, n_coarse, apart):
    """Whether the elements of a coarse level look up the cells of a level ``apart`` levels finer
    (up to ``(2^apart + 1)^3`` each) rather than the fine ones the coarse cells (about 4 each)."""
    span = 2.0 ** apart + 1.0  # float: (2^apart + 1)^3 overflows int64 for levels far apart
    return n_coarse * span * span * span < 4.0 * n_fine


@numba.njit(cache=True)
def _corner_slots(grid):
    """Per level, the slot of every element there that holds its box's lower corner (one per element)."""
    scale, level, toff, tmask, start, items, key, box = grid
    out = []
    for L in range(tmask.shape[0]):
        s = scale[L]
        here = np.empty(start[toff[L + 1]] - start[toff[L]], np.int64)
        k = 0
        for p in range(start[toff[L]], start[toff[L + 1]]):
            if _corner_key(box, p, p, s) == key[p]:
                here[k] = p
                k += 1
        out.append(here[:k])
    return out


@numba.njit(cache=True)
def _slots(grid, qlo, qhi, min_level, max_level, buf):
    """Slots, on levels ``min_level`` to ``max_level - 1``, of the elements whose boxes overlap the box
    ``qlo, qhi``, one per element (the cell holding the lower corner of the intersection), into ``buf``;
    returns (buf, count). ``buf`` grows when full."""
    scale, level, toff, tmask, start, items, key, box = grid
    count = 0
    for L in range(min_level, min(max_level, tmask.shape[0])):
        if tmask[L] < 0:
            continue
        s = scale[L]
        for ix in range(_cell(qlo[0], s), _cell(qhi[0], s) + 1):
            for iy in range(_cell(qlo[1], s), _cell(qhi[1], s) + 1):
                for iz in range(_cell(qlo[2], s), _cell(qhi[2], s) + 1):
                    here = _key(ix, iy, iz)
                    b = toff[L] + _hash(ix, iy, iz, tmask[L])
                    if count + start[b + 1] - start[b] > buf.shape[0]:
                        bigger = np.empty(2 * buf.shape[0] + start[b + 1] - start[b], np.int64)
                        bigger[:count] = buf[:count]
                        buf = bigger
                    for p in range(start[b], start[b + 1]):
                        if box[p, 0] > qhi[0]:
                            break  # the bucket is sorted by lower x
                        # kept if in this cell, overlapping, and its corner cell (no branches: see pairs)
                        buf[count] = p
                        count += ((key[p] == here) & _overlap(box, p, qlo, qhi)
                                  & (_key(_cell(max(qlo[0], box[p, 0]), s), _cell(max(qlo[1], box[p, 1]), s),
                                          _cell(max(qlo[2], box[p, 2]), s)) == here))
    return buf, count


@numba.njit(cache=True)
def gather(grid, qlo, qhi, buf):
    """Elements whose boxes overlap the box ``qlo, qhi``, each once, into ``buf``; returns (buf, count).

    ``buf`` grows when full.
    """
    buf, count = _slots(grid, qlo, qhi, 0, 64, buf)
    items = grid.items
    for i in range(count):
        buf[i] = items[buf[i]]
    return buf, count


def pairs_with(grid, lo: np.ndarray, hi: np.ndarray, elements: np.ndarray) -> np.ndarray:
    """The rows of :func:`pairs` with an element in ``elements``, in ascending order: each such element's
    box (``lo[e], hi[e]``, as the grid was built from) is looked up once. When a few elements move
    among many this costs a small part of listing every pair and keeping those."""
    chosen = np.zeros(len(lo), bool)
    chosen[elements] = True
    out = _pairs_with(grid, lo, hi, np.flatnonzero(chosen), chosen)
    return out[np.lexsort((out[:, 1], out[:, 0]))]


@numba.njit(cache=True)
def _pairs_with(grid, lo, hi, elements, chosen):
    buf = np.empty(256, np.int64)
    out = np.empty((max(1024, _PAIRS_PER_SLOT * elements.shape[0]), 2), np.int64)
    count = 0
    for a in elements:
        buf, k = gather(grid, lo[a], hi[a], buf)
        out = _room(out, count, k)
        for i in range(k):
            g = buf[i]
            if g == a or (chosen[g] and g < a):
                continue  # itself, or a pair reported from g's look-up
            out[count, 0], out[count, 1] = min(a, g), max(a, g)
            count += 1
    return out[:count]


def cell_size(lo: np.ndarray, hi: np.ndarray, typical: float) -> float:
    """A level-0 cell of size ``typical``, enlarged where the boxes' extent would overflow the packed cells."""
    if not len(lo):
        return max(typical, tol.zero)
    reach = float(max(np.abs(lo).max(), np.abs(hi).max()))
    return max(typical, reach / _SPAN, tol.zero)
