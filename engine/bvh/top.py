"""The sampled top levels of the build (`grow_top`), for meshes of more than TOP_MIN triangles.

Where every node of a pass would be binned on a sample anyway, the passes run on the sampled triangles alone: the
others wait in pools by Morton-index stride and walk down the chosen planes once, in cache-sized blocks (`_walk`),
when a node needs a denser sample or the top is done. In the final walk, triangles whose node splits at no later
level leave early for the node they end in (`_walk_tails`); the odd-indexed triangles, half the mesh, first take the
node of a Morton neighbour when their centre is inside its region, the bounds that the planes above it set
(`_regions`), and walk only where it is not. The top is checked against the depth cap with exact counts at the end.
Each pass's sample selection, cell statistics and partition of the subset run in parts on the pool's threads.
"""

from __future__ import annotations

import numpy as np

from ..parallel import cuts as _cuts, run as _parallel
from .binning import GRID4_MAX, SAMPLE4, SAMPLE8, ceil_log2, cell_stats, grid_sah
from .pack import Record

#: Meshes of more than TOP_MIN triangles build their sampled top levels on a subset; TOP_BLOCK triangles at a time
#: walk down its planes.
TOP_MIN = 1 << 14
TOP_BLOCK = 1 << 15
#: Sample targets of the top levels (the same as below them).
TOP_SAMPLE8 = SAMPLE8
TOP_SAMPLE4 = SAMPLE4
#: Nodes of at most TOP_STOP (estimated) triangles leave the top.
TOP_STOP = SAMPLE4


def grow_top(box, cen, cen_rows, max_leaf: int, max_depth: int, threads: int = 1):
    """The top of the tree, where every node is binned on a sample: the passes see only the sampled triangles
    (every 2^rate-th in Morton order, as in grow.py), the others wait in pools by their number of trailing zero
    bits (a pool walks down the levels made so far when a node needs a denser sample), and once the top is done all
    of them walk down its planes (_walk). A node stops here (and goes on in grow.py's passes, with exact counts)
    once it is too small to be sampled, it has no plane, a child could be a leaf, or the depth cap could bind below
    it (max_leaf * 2^levels left < 4 x its estimated triangles). Returns None where the root stops, else (records of the
    top, the node of every triangle, then count, depth and binning domain of every such node); also None where the
    exact counts would break the depth cap (the top's estimates were off)."""
    n = box.shape[1]
    dom = np.concatenate([box[:3].min(axis=1), -box[3:].min(axis=1)]).reshape(6, 1).astype(np.float32)
    count = np.array([n], dtype=np.int64)  # estimates below the root
    depth = np.zeros(1, dtype=np.int64)
    frozen = np.zeros(1, dtype=bool)
    levels, splits, depth_at = [], [], []  # per level: (axis, split, nxt) for _walk; which nodes split; depths
    sub_tid = sub_slot = have = None  # the subset; node k holds every triangle with >= have[k] trailing zeros
    tiers = {}  # z -> [tids with exactly z trailing zeros not in the subset, their node, at level]
    parked = []  # (tids, node, level) of stopped nodes
    while True:
        k = count.size
        room = np.minimum(max_depth - depth - 1, 40)
        grid = np.where(count <= GRID4_MAX, 4, 8).astype(np.int64)
        target = np.where(grid == 8, TOP_SAMPLE8, TOP_SAMPLE4)
        rate_log = np.maximum(ceil_log2(count) - ceil_log2(target), 1)
        elig = ~frozen & (count > TOP_STOP) & (room >= 0) & (np.left_shift(max_leaf, np.maximum(room, 0)) >= 4 * count)
        if not elig.any():
            break
        if sub_tid is None:
            r0 = int(rate_log[0])
            sub_tid = np.arange(0, n, 1 << r0, dtype=np.intp)
            sub_slot = np.zeros(sub_tid.size, dtype=np.intp)
            have = np.array([r0], dtype=np.int64)
            for z in range(1, r0):
                tiers[z] = [np.arange(1 << z, n, 2 << z, dtype=np.intp), None, 0]
        needy = elig & (rate_log < have)
        if needy.any():  # denser samples: the pools they need walk down to this level
            lvl = len(levels)
            add_t, add_s = [sub_tid], [sub_slot]
            for z in range(int(rate_log[needy].min()), int(have[needy].max())):
                want = needy & (rate_log <= z) & (have > z)
                if not want.any() or z not in tiers:
                    continue
                t, nd, l0 = tiers[z]
                nd = _walk_blocks(t, nd, levels[l0:], cen_rows, threads)
                take = want.take(nd)
                add_t.append(t[take])
                add_s.append(nd[take])
                tiers[z] = [t[~take], nd[~take], lvl]
            # sorted runs, merged by a stable value sort of (tid, slot) packed in one int64: in Morton order the
            # gathers stay local
            packed = np.concatenate(add_t)
            packed <<= 32
            packed |= np.concatenate(add_s)
            packed.sort(kind="stable")
            sub_slot = packed & 0xFFFFFFFF
            packed >>= 32
            sub_tid = packed
            have = np.where(needy, rate_log, have)

        # statistics of the eligible nodes from their samples (every 2^rate_log-th triangle)
        # (an ineligible node has mask -1: it samples nothing)
        mask = np.where(elig, (np.int64(1) << rate_log) - 1, -1)
        ext = dom[3:] - dom[:3]
        inv = np.where(ext > 0, grid / np.where(ext > 0, ext, 1), 0).astype(np.float32)
        off = (-dom[:3] * inv).astype(np.float32)
        gmax = (grid - 1).astype(np.int32)
        cell_base = np.zeros(k, dtype=np.int64)
        groups, n_cells = [], 0
        for gsize in (4, 8):
            members = np.flatnonzero(elig & (grid == gsize))
            if members.size:
                cell_base[members] = n_cells + np.arange(members.size) * gsize**3
                groups.append((gsize, members, n_cells))
                n_cells += members.size * gsize**3
        grid32 = grid.astype(np.int32)

        def stats(lo, hi):  # count and box of every cell from the samples among the subset's [lo, hi)
            return cell_stats(cen, box, sub_tid[lo:hi], sub_slot[lo:hi], mask, inv, off, gmax, grid32, cell_base,
                              None, n_cells)[1:]

        # in parts on the pool's threads where the subset is large; sums and minima are exact in any order
        cuts = _cuts(sub_tid.size, threads, TOP_BLOCK * 2)
        parts = _parallel([lambda a=a, b=b: stats(a, b) for a, b in zip(cuts[:-1], cuts[1:])], threads)
        cell_count, cell_box = parts[0]
        for cnt, cbox in parts[1:]:
            cell_count += cnt
            np.minimum(cell_box, cbox, out=cell_box)
        axis = np.zeros(k, dtype=np.int64)
        plane = np.zeros(k, dtype=np.int64)
        found = np.zeros(k, dtype=bool)
        child_dom = np.empty((2, 6, k), dtype=np.float32)
        for gsize, members, first in groups:
            stop = first + members.size * gsize**3
            res = grid_sah(cell_count[first:stop], cell_box[:, first:stop], gsize,
                           np.zeros(members.size, dtype=bool), np.zeros(members.size, dtype=np.int64))
            axis[members], plane[members], found[members], child_dom[:, :, members] = res
        cols = np.arange(k)
        with np.errstate(divide="ignore", invalid="ignore"):
            split = (plane - off[axis, cols]) / np.where(inv[axis, cols] > 0, inv[axis, cols], 1)  # world space
        split[~(elig & found)] = np.inf

        # the subset goes down; a node splits only where both children keep more than max_leaf of it
        def sides(lo, hi):  # child slot (2 node + side) of the subset's [lo, hi), and their counts
            sl = sub_slot[lo:hi]
            a_t = axis.take(sl)
            a_t += sub_tid[lo:hi] * 3
            d = 2 * sl
            d += cen_rows.take(a_t) >= split.take(sl)
            return d, np.bincount(d, minlength=2 * k)

        parts = _parallel([lambda a=a, b=b: sides(a, b) for a, b in zip(cuts[:-1], cuts[1:])], threads)
        dest = parts[0][0] if len(parts) == 1 else np.concatenate([d for d, _ in parts])
        sub_cnt = sum(c for _, c in parts).reshape(k, 2)
        do = elig & found & (sub_cnt > max_leaf).all(axis=1)
        if not do.any():
            break
        first_new = np.cumsum(1 + do) - (1 + do)
        nxt = np.stack([first_new, first_new + do], axis=1)  # (k, 2): pass-through nodes keep one successor
        levels.append((axis, split, nxt.reshape(-1)))
        splits.append(do)
        depth_at.append(depth)
        n_next = int(first_new[-1] + 1 + do[-1])
        new_count = np.empty(n_next, dtype=np.int64)
        new_depth = np.empty(n_next, dtype=np.int64)
        new_dom = np.empty((6, n_next), dtype=np.float32)
        new_frozen = np.ones(n_next, dtype=bool)
        stay = ~do
        new_count[first_new[stay]] = count[stay]
        new_depth[first_new[stay]] = depth[stay]
        new_dom[:, first_new[stay]] = dom[:, stay]
        for side in (0, 1):
            at = nxt[do, side]
            new_count[at] = sub_cnt[do, side] << have[do]
            new_depth[at] = depth[do] + 1
            new_dom[:, at] = child_dom[side][:, do]
            new_frozen[at] = False
        live = do.take(sub_slot)
        if not live.all():
            parked.append((sub_tid[~live], sub_slot[~live], len(levels) - 1))
            sub_tid, dest = sub_tid[live], dest[live]
        sub_slot = nxt.reshape(-1).take(dest)
        new_have = np.empty(n_next, dtype=np.int64)
        new_have[first_new] = have
        new_have[first_new + do] = have
        count, depth, dom, frozen, have = new_count, new_depth, new_dom, new_frozen, new_have
    if not levels:
        return None

    slot = np.empty(n, dtype=np.intp)
    tails = _walk_tails(levels)
    slot[sub_tid] = sub_slot

    def walk_into_slot(t, nd, l0):  # disjoint triangles per task
        slot[t] = _walk(t, nd, levels[l0:], cen_rows, tails)

    tasks = []
    for t, nd, l0 in list(tiers.values()) + parked:
        for b in range(0, t.size, 4 * TOP_BLOCK):
            part = slice(b, b + 4 * TOP_BLOCK)
            tasks.append(lambda t=t[part], nd=None if nd is None else nd[part], l0=l0: walk_into_slot(t, nd, l0))
    _parallel(tasks, threads)
    # every triangle with a trailing zero bit (even index) has its node; the others most often end in the node of
    # the triangle before them (Morton order): a test against that node's region, and a walk where it fails
    lo, hi = _regions(levels)

    def guess_block(s):  # the odd triangles of [s, s + 2 TOP_BLOCK)
        miss = []
        e = min(s + 2 * TOP_BLOCK, n)
        guess = slot[s - 1:e - 1:2]
        inside = None
        for a in range(3):
            c = cen[a, s:e:2]
            ok = c >= lo[a].take(guess)
            ok &= c < hi[a].take(guess)
            inside = ok if inside is None else inside & ok
        slot[s:e:2] = guess
        out = np.flatnonzero(~inside)
        if out.size:  # then the node of the triangle after them
            t = out * 2 + s
            if t[-1] + 1 >= n:  # the last triangle has none after it
                miss.append(t[-1:])
                t = t[:-1]
            guess = slot.take(t + 1)
            inside = None
            for a in range(3):
                c = cen[a].take(t)
                ok = c >= lo[a].take(guess)
                ok &= c < hi[a].take(guess)
                inside = ok if inside is None else inside & ok
            slot[t] = guess
            miss.append(t[~inside])
        if miss:
            miss = np.concatenate(miss)
            slot[miss] = _walk(miss, None, levels, cen_rows, tails)

    # blocks read only even slots (set above) and write only their own odd ones
    _parallel([lambda s=s: guess_block(s) for s in range(1, n, 2 * TOP_BLOCK)], threads)
    count = np.bincount(slot, minlength=count.size).astype(np.int64)
    # the depth cap, with the exact counts: every node of the top within its limit (else: build without the top)
    sizes = count
    for lv in range(len(levels) - 1, -1, -1):
        nxt = levels[lv][2].reshape(-1, 2)
        do = splits[lv]
        kids = sizes.take(nxt)
        if (kids[do] > max_leaf << np.minimum(max_depth - depth_at[lv][do, None] - 1, 40)).any():
            return None
        sizes = np.where(do, kids[:, 0] + kids[:, 1], kids[:, 0])
    # records: a split node's children are its row in the next level's record, or (passing through the levels
    # below) a starting node of grow.py's passes, whose first record will be number len(levels)
    n_lv = len(levels)
    res_rec = np.full(count.size, n_lv, dtype=np.int64)
    res_child = np.arange(count.size, dtype=np.int64)
    records = [None] * n_lv
    for lv in range(n_lv - 1, -1, -1):
        do = splits[lv]
        nxt = levels[lv][2].reshape(-1, 2)
        ch = nxt[do]
        records[lv] = Record(child=res_child.take(ch), rec=res_rec.take(ch))
        here_rec = np.where(do, lv, res_rec.take(nxt[:, 0]))
        here_child = np.where(do, np.cumsum(do) - 1, res_child.take(nxt[:, 0]))
        res_rec, res_child = here_rec, here_child
    return records, slot, count, depth, dom


def _walk_blocks(tids, node, levels, cen_rows, threads):
    """_walk in blocks of 4 TOP_BLOCK triangles on the pool's threads (the same nodes in any case)."""
    if threads <= 1 or tids.size <= 4 * TOP_BLOCK:
        return _walk(tids, node, levels, cen_rows)
    step = 4 * TOP_BLOCK
    parts = _parallel([lambda b=b: _walk(tids[b:b + step], None if node is None else node[b:b + step], levels,
                                         cen_rows) for b in range(0, tids.size, step)], threads)
    return np.concatenate(parts)


def _walk(tids: np.ndarray, node: np.ndarray | None, levels, cen_rows: np.ndarray, tails=None) -> np.ndarray:
    """Node of the last of `levels` that each triangle `tids` reaches from `node` (its node in the first of them;
    None: the root), walking down their planes in cache-sized blocks with the same comparison as the top passes'
    partition. tails (_walk_tails of the same levels, aligned with their end): triangles whose node splits at no
    later level leave the walk early for the node they would reach."""
    out = np.zeros(tids.size, dtype=np.intp) if node is None else node.astype(np.intp, copy=True)
    if not levels:
        return out
    if tails is not None:
        tails = tails[len(tails) - len(levels):]
    for s in range(0, tids.size, TOP_BLOCK):
        t3 = tids[s:s + TOP_BLOCK] * 3
        nd = out[s:s + TOP_BLOCK]
        pos = None  # positions in the block of the triangles still walking (None: all)
        for i, (axis, split, nxt) in enumerate(levels):
            if tails is not None and tails[i] is not None:
                dead_at, final = tails[i]
                d = dead_at.take(nd)
                n_dead = int(np.count_nonzero(d))
                if n_dead * 4 > nd.size:
                    done = np.flatnonzero(d)
                    live = np.flatnonzero(~d)
                    if pos is None:
                        out[s + done] = final.take(nd.take(done))
                        pos = live + s
                    else:
                        out[pos.take(done)] = final.take(nd.take(done))
                        pos = pos.take(live)
                    nd, t3 = nd.take(live), t3.take(live)
                    if not nd.size:
                        break
            a = axis.take(nd)
            a += t3
            right = cen_rows.take(a) >= split.take(nd)
            nd *= 2
            nd += right
            nd = nxt.take(nd)
        if pos is None:
            out[s:s + t3.size] = nd
        elif nd.size:
            out[pos] = nd
    return out


def _regions(levels):
    """Bounds (lo, hi), (3, K) float64, of the centres that _walk takes to each node of the last of `levels`: a
    centre c reaches node j when lo[:, j] <= c < hi[:, j] (the same comparisons as the walk; a NaN bound admits
    nothing)."""
    lo = np.full((3, 1), -np.inf)
    hi = np.full((3, 1), np.inf)
    for axis, split, nxt in levels:
        nx = nxt.reshape(-1, 2)
        n_next = int(nxt.max()) + 1
        new_lo = np.empty((3, n_next))
        new_hi = np.empty((3, n_next))
        for side in (0, 1):
            new_lo[:, nx[:, side]] = lo
            new_hi[:, nx[:, side]] = hi
        d = np.flatnonzero(nx[:, 0] != nx[:, 1])
        a, sd = axis.take(d), split.take(d)
        new_hi[a, nx[d, 0]] = np.minimum(hi[a, d], sd)
        new_lo[a, nx[d, 1]] = np.maximum(lo[a, d], sd)
        lo, hi = new_lo, new_hi
    return lo, hi


def _walk_tails(levels):
    """Per level (None where few nodes qualify): which of its nodes split at no level from there on (dead_at), and
    the node of the last level each of them ends in (final)."""
    tails = [None] * len(levels)
    dead = None
    final = None
    for i in range(len(levels) - 1, -1, -1):
        nxt = levels[i][2].reshape(-1, 2)
        succ = nxt[:, 0]
        through = succ == nxt[:, 1]
        if dead is None:
            dead, final = through, succ
        else:
            dead = through & dead.take(succ)
            final = final.take(succ)
        if dead.mean() > 0.2:
            tails[i] = (dead, final)
    return tails
