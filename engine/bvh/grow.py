"""The level-synchronous binned SAH build: the tree grows top-down in passes over the Morton-sorted triangles.

Every node of a pass is handled by the same numpy calls, so Python loops run over passes, never over nodes or
triangles. Each active triangle carries the slot of its node.
  a. Each node bins its triangles' centres on a G^3 grid (binning.py); one bincount and six np.minimum.at calls give
     the count and box of every cell. Big nodes take these statistics from a Morton-stratified sample (every 2^j-th
     triangle).
  b. SAH over the planes of each axis (binning.py); nodes on 2^3 grids also choose their children's splits, so
     those triangles go down two levels in one pass.
  c. Every triangle moves to the side of the chosen plane, computed with exactly the same float32 arithmetic as its
     cell, so the counts of nodes binned without sampling are exact.
  d. Children with at most max_leaf triangles become leaves; their triangles leave the active set (pack.Leaves).
A node with no usable plane (all centres in one cell, e.g. coincident centroids) is split at its median in Morton
order.

Depth cap: a node at depth d may hold at most max_leaf * 2^(max_depth - d) triangles. Planes that would leave a
child above its cap are not used, and a node whose counts are only estimated and could break the cap is split at
its median. So leaves are never deeper than max_depth, whatever the geometry, and the GPU traversal stack
(BVH_STACK_SIZE) cannot overflow.

Once every node holds at most CHUNK triangles, groups of nodes (independent subtrees) are finished separately on
cache-sized copies of their data, on the pool's threads, and merged in a fixed order.

C: where engine/native.py has its library, the pass loop runs in C (native.grow) up to the chunk groups and in
each group, with the arithmetic, order and tie rules of the numpy steps here, which stay the reference and the
fallback: the same records and leaves, number for number. It keeps each node's triangles together and bins them
node by node, where numpy bins every node of a pass at once.
"""

from __future__ import annotations

import numpy as np

from .. import native
from ..parallel import run as _parallel
from .binning import (
    GRID2_MAX,
    GRID4_MAX,
    OCTANT_TABLES,
    SAMPLE4,
    SAMPLE8,
    ceil_log2,
    cell_axis,
    cell_stats,
    grid_sah,
    octant_sah,
)
from .pack import Leaves, Record

#: Once every node holds at most CHUNK triangles, groups of about CHUNK are finished separately (cache-sized data).
CHUNK = 1 << 17


def grow(box: np.ndarray, cen: np.ndarray, max_leaf: int, max_depth: int, stat_boxes: bool = True, threads: int = 1):
    """Build the topology: records of interior nodes (node 0 = record 0, row 0 is the root), the leaf of every
    (sorted) triangle, and every leaf's size and depth."""
    n_tri = box.shape[1]
    dom = np.concatenate([box[:3].min(axis=1), -box[3:].min(axis=1)]).reshape(6, 1)  # binning domain lo, hi
    return _grow_from(
        box,
        cen,
        np.arange(n_tri, dtype=np.intp),
        np.zeros(n_tri, dtype=np.intp),
        np.array([n_tri], dtype=np.int64),
        np.zeros(1, dtype=np.int64),
        dom,
        max_leaf,
        max_depth,
        CHUNK,
        stat_boxes=stat_boxes,
        threads=threads,
    )


def trivial(box: np.ndarray, n_tri: int):
    """0 or 1 triangle: a root whose left child is a leaf with the mesh and whose right child is an empty leaf."""
    rec = Record(child=np.array([[0, 1]], dtype=np.int64), rec=np.full((1, 2), -1, dtype=np.int64))
    leaves = Leaves()
    leaves.add(
        box,
        np.arange(n_tri, dtype=np.intp),
        np.zeros(n_tri, dtype=np.int64),
        np.array([n_tri, 0], dtype=np.int64),
        np.ones(2, np.int64),
    )
    return [rec], leaves


def _grow_from(
    box, cen, tid, slot, count, depth, dom, max_leaf: int, max_depth: int, chunk, stat_boxes=True, threads: int = 1
):
    """The pass loop, from a set of active nodes: tid (increasing indices into box / cen) and slot of every
    active triangle; count, depth (the root is at 0) and binning domain (6, K) of every active node.

    Once every node holds at most `chunk` triangles, the nodes are split into independent groups of about that
    many triangles, and each group is finished by its own loop on compact copies of its data (cache-sized
    arrays). Returns records (the first record's rows are the starting nodes) and the leaves (Leaves).

    stat_boxes: a leaf made by a node binned without sampling (and not split at its median) takes its box from the
    cell statistics, the union of the cells on its side, which is exactly the union of its triangles' boxes (they
    are partitioned with the cells' own arithmetic); the others, and all where stat_boxes is false, reduce their
    triangles' boxes.
    """
    n_tri = box.shape[1]
    leaves = Leaves()
    records: list[Record] = []
    n_leaves = 0
    # pending: (record index the last pass's new nodes will live in, records that point at it)
    pending = None
    done = native.grow(
        box, cen, tid, slot, count, depth, dom, max_leaf, max_depth, stat_boxes, chunk, *OCTANT_TABLES, threads=threads
    )
    if done is not None:  # in C, up to the end or the chunk groups
        made, batch, state = done
        records.extend(Record(child=child, rec=rec) for child, rec in made)
        leaves.append(*batch)
        if state is None:
            return records, leaves
        n_leaves = batch[1].size
        tid, slot, count, depth, dom, pending = state
    cen_rows = None
    while count.size:
        if chunk and pending and tid.size > chunk and count.max() <= chunk:
            n_leaves = _grow_chunks(
                box,
                cen,
                tid,
                slot,
                count,
                depth,
                dom,
                max_leaf,
                max_depth,
                chunk,
                records,
                pending,
                leaves,
                n_leaves,
                stat_boxes,
                threads,
            )
            break
        if depth.max() >= max_depth:  # the caps make this unreachable
            raise AssertionError("BVH depth cap violated")
        k_nodes = count.size
        room = np.minimum(max_depth - depth - 1, 40)  # levels left below the children (2^40 > any mesh)
        cap = np.minimum(np.left_shift(max_leaf, room), n_tri)  # children's size limit
        cap2 = np.where(room >= 1, np.minimum(np.left_shift(max_leaf, np.maximum(room - 1, 0)), n_tri), 0)

        # grid and sampling per node
        grid = np.where(count <= GRID2_MAX, 2, np.where(count <= GRID4_MAX, 4, 8)).astype(np.int64)
        target = np.where(grid == 8, SAMPLE8, SAMPLE4)
        rate_log = np.where(grid == 2, 0, np.maximum(ceil_log2(count) - ceil_log2(target), 0))
        if count[rate_log > 0].sum() * 4 < tid.size:  # few triangles in sampled nodes: bin every one
            rate_log[:] = 0
        exact = rate_log == 0
        ext = dom[3:] - dom[:3]
        inv = np.where(ext > 0, grid / np.where(ext > 0, ext, 1), 0).astype(np.float32)
        off = (-dom[:3] * inv).astype(np.float32)  # cell coordinate = c * inv + off
        gmax = (grid - 1).astype(np.int32)

        # cell (x, y, z) of node k sits at cell_base[k] + ((x * G + y) * G + z) * cell_step[k]. Nodes with the
        # same grid size form a group with adjacent cells: node-major (step 1) for 4^3 and 8^3 grids, which
        # keeps the scatter below local; cell-major (step = group size) for the many small 2^3 grids, which the
        # octant SAH reads without a transpose.
        by_grid = np.argsort(grid, kind="stable")
        cell_base = np.empty(k_nodes, dtype=np.int64)
        cell_step = np.ones(k_nodes, dtype=np.int64)
        groups = []
        n_cells = 0
        for gsize in (2, 4, 8):
            members = by_grid[grid.take(by_grid) == gsize]
            if members.size:
                local = np.arange(members.size)
                if gsize == 2:
                    cell_base[members] = n_cells + local
                    cell_step[members] = members.size
                else:
                    cell_base[members] = n_cells + local * gsize**3
                groups.append((gsize, members, n_cells))
                n_cells += members.size * gsize**3

        # statistics: one cell per (sampled) triangle
        mask = None if exact.all() else (np.int64(1) << rate_log) - 1
        cells, cell_count, cell_box = cell_stats(
            cen,
            box,
            tid,
            slot,
            mask,
            inv,
            off,
            gmax,
            grid.astype(np.int32),
            cell_base,
            cell_step,
            n_cells,
            want_cells=mask is None,
        )

        # SAH per group. Nodes on 2^3 grids also choose their children's splits from the same statistics
        # (each half is four cells: one plane along each of the two other axes), so that their triangles move
        # down two levels in this pass.
        axis = np.zeros(k_nodes, dtype=np.int64)
        plane = np.zeros(k_nodes, dtype=np.int64)
        found = np.zeros(k_nodes, dtype=bool)
        child_dom = np.empty((2, 6, k_nodes), dtype=np.float32)
        axis2 = np.zeros((2, k_nodes), dtype=np.int64)  # per side: the child's axis (plane: the middle)
        found2 = np.zeros((2, k_nodes), dtype=bool)
        grand_dom = np.empty((2, 2, 6, k_nodes), dtype=np.float32)  # [side, side of the child]
        for gsize, members, first in groups:
            stop = first + members.size * gsize**3
            cnt_g, box_g, ex_g = cell_count[first:stop], cell_box[:, first:stop], exact.take(members)
            if gsize == 2:
                res = octant_sah(cnt_g, box_g, ex_g, cap.take(members), cap2.take(members), max_leaf)
                axis[members], found[members], child_dom[:, :, members] = res[:3]
                plane[members] = 1
                axis2[:, members], found2[:, members], grand_dom[:, :, :, members] = res[3:]
            else:
                res = grid_sah(cnt_g, box_g, gsize, ex_g, cap.take(members))
                axis[members], plane[members], found[members], child_dom[:, :, members] = res
        # nodes whose counts are estimates and could break the depth cap are split at the median
        median = ~found | (~exact & (count > cap))
        found2 &= ~median

        # every active triangle goes left or right, and on 2^3 grids on into a grandchild
        a_t = axis.take(slot)
        if exact.all():  # the cells of all triangles are at hand
            a_t *= slot.size
            a_t += np.arange(slot.size)
            right = cells.reshape(-1).take(a_t) >= plane.take(slot)
        else:
            found2[:] = False
            at_node = slot * 3
            at_node += a_t
            a_t += tid * 3
            if cen_rows is None:
                cen_rows = np.ascontiguousarray(cen.T).reshape(-1)  # (x, y, z) of triangle i at 3 i .. 3 i + 2
            c_t = cen_rows.take(a_t)  # each triangle's centre on its node's axis
            if not exact.any():  # estimates only: a plain plane test in world space is enough
                with np.errstate(divide="ignore", invalid="ignore"):
                    split = (plane - off) / np.where(inv > 0, inv, 1)  # (3, K)
                right = c_t >= split.T.reshape(-1).take(at_node)
            else:  # the same arithmetic as the cells, so that exact counts stay exact
                c_t = cell_axis(c_t, inv.T.reshape(-1), off.T.reshape(-1), gmax.take(slot), at_node)
                right = c_t >= plane.take(slot)
        if median.any():
            _median_sides(right, slot, count, median)
        dest = 2 * slot + right  # outcome: child 2k + side, or grandchild 2K + 2 child + side
        split2 = found2.T.reshape(-1)  # (2K,) the child is split in this pass too
        if split2.any():
            moving = np.flatnonzero(split2.take(dest))
            child = dest.take(moving)
            at = axis2.T.reshape(-1).take(child) * slot.size
            at += moving
            dest[moving] = 2 * k_nodes + 2 * child + cells.reshape(-1).take(at)  # grid 2: the plane is cell 1
        n_out = 6 * k_nodes
        ocount = np.bincount(dest, minlength=n_out)

        # outcomes: intermediate nodes (children split here), new active nodes, leaves
        is_grand = np.arange(n_out) >= 2 * k_nodes
        used = np.concatenate([~split2, np.repeat(split2, 2)])
        inner = used & (ocount > max_leaf)
        leaf = used & ~inner
        n_inner, n_leaf, n_mid = int(inner.sum()), int(leaf.sum()), int(split2.sum())
        out_index = np.full(n_out, -1, dtype=np.int64)
        out_index[inner] = np.arange(n_inner)
        out_index[leaf] = n_leaves + np.arange(n_leaf)
        out_index[: 2 * k_nodes][split2] = np.arange(n_mid)
        rec_here = len(records)
        rec_mid = rec_here + 1
        rec_next = rec_here + (2 if n_mid else 1)
        out_rec = np.where(inner, rec_next, -1)
        out_rec[: 2 * k_nodes][split2] = rec_mid
        records.append(
            Record(child=out_index[: 2 * k_nodes].reshape(k_nodes, 2), rec=out_rec[: 2 * k_nodes].reshape(k_nodes, 2))
        )
        if n_mid:
            grand = 2 * k_nodes + 2 * np.flatnonzero(split2)
            records.append(
                Record(
                    child=np.stack([out_index[grand], out_index[grand + 1]], axis=1),
                    rec=np.stack([out_rec[grand], out_rec[grand + 1]], axis=1),
                )
            )
        pending = (rec_next, [rec_here, rec_mid] if n_mid else [rec_here])
        out_depth = np.concatenate([np.repeat(depth, 2), np.repeat(depth, 4)]) + 1 + is_grand
        n_leaves += n_leaf

        # the next pass
        new_slot = out_index.take(dest)
        new_slot[~inner.take(dest)] = -1
        stay = new_slot >= 0
        # domains of the outcomes (lo xyz, hi xyz): children of median splits keep the parent's
        cdom = np.where(median[None, None, :], dom[None].astype(np.float32), child_dom)  # (2, 6, K)
        gdom = grand_dom.transpose(2, 3, 0, 1).reshape(6, 4 * k_nodes)  # grandchild 2 child + side order
        odom = np.concatenate([cdom.transpose(1, 2, 0).reshape(6, 2 * k_nodes), gdom], axis=1)
        if n_leaf:  # this pass's leaves, in id order (their triangles in Morton order)
            gone = np.flatnonzero(~stay)
            known = None
            if stat_boxes:  # (exact boxes, which leaves have one)
                lb = odom[:, leaf]
                lb[3:] *= -1
                known = (lb, np.concatenate([np.repeat(exact & ~median, 2), np.repeat(split2, 2)])[leaf])
            leaves.add(
                box,
                tid.take(gone),
                out_index.take(dest.take(gone)) - (n_leaves - n_leaf),
                ocount[leaf],
                out_depth[leaf],
                known,
            )
        if not stay.all():
            tid, new_slot = tid[stay], new_slot[stay]
        slot = new_slot
        count = ocount[inner]
        depth = out_depth[inner]
        dom = odom[:, inner]
    return records, leaves


def _grow_chunks(
    box,
    cen,
    tid,
    slot,
    count,
    depth,
    dom,
    max_leaf,
    max_depth,
    chunk,
    records,
    pending,
    leaves,
    n_leaves,
    stat_boxes,
    threads=1,
):
    """Finish the active nodes group by group (see _grow_from); appends to records and the leaf lists, points the
    last pass's references at each group's first record, and returns the new leaf count."""
    k_nodes = count.size
    group = (np.cumsum(count) - 1) // chunk  # consecutive nodes, about `chunk` triangles a group
    _, group = np.unique(group, return_inverse=True)
    n_groups = int(group.max()) + 1
    order = np.argsort(group.astype(np.uint16 if n_groups < 1 << 16 else np.int64).take(slot), kind="stable")
    # tid: increasing indices, so all of them is the identity
    tid, slot = (order if tid.size == box.shape[1] else tid.take(order)), slot.take(order)
    ends = np.cumsum(np.bincount(group, weights=count, minlength=n_groups).astype(np.int64))
    local = np.empty(k_nodes, dtype=np.int64)
    node_rec = np.empty(k_nodes, dtype=np.int64)
    spans = []
    for g, (lo, hi) in enumerate(zip(np.r_[0, ends[:-1]], ends)):
        nodes = np.flatnonzero(group == g)
        local[nodes] = np.arange(nodes.size)
        spans.append((nodes, tid[lo:hi], slot[lo:hi]))

    def finish_group(nodes, t, s):
        return _grow_from(
            box.take(t, axis=1),
            cen.take(t, axis=1),
            np.arange(t.size, dtype=np.intp),
            local.take(s),
            count[nodes],
            depth[nodes],
            dom[:, nodes],
            max_leaf,
            max_depth,
            None,
            stat_boxes=stat_boxes,
        )

    # the groups are independent: they run on the pool's threads (numpy releases the GIL in most of their work),
    # and are merged here in group order, so the tree does not depend on the number of threads
    subs = _parallel([lambda span=span: finish_group(*span) for span in spans], threads)
    for (nodes, t, _), (sub_records, sub_leaves) in zip(spans, subs):
        node_rec[nodes] = len(records)
        for rc in sub_records:
            inner = rc.rec >= 0
            records.append(
                Record(
                    child=np.where(inner, rc.child, rc.child + n_leaves),
                    rec=np.where(inner, rc.rec + node_rec[nodes[0]], -1),
                )
            )
        n_leaves += leaves.extend(sub_leaves, t)
    # the last pass pointed its new nodes at (rec_next, slot): now (their group's first record, local row)
    rec_next, referrers = pending
    for r in referrers:
        rc = records[r]
        to_next = rc.rec == rec_next
        slots = rc.child[to_next]
        rc.rec[to_next] = node_rec.take(slots)
        rc.child[to_next] = local.take(slots)
    return n_leaves


def _median_sides(right, slot, count, median):
    """Split the nodes flagged in `median` at their median in Morton order (triangles are in that order)."""
    idx = np.flatnonzero(median.take(slot))
    s = slot.take(idx)
    o = np.argsort(s, kind="stable")
    s_sorted = s.take(o)
    first = np.flatnonzero(np.r_[True, s_sorted[1:] != s_sorted[:-1]])
    starts = np.repeat(first, np.diff(np.r_[first, s_sorted.size]))
    rank = np.arange(s_sorted.size) - starts
    right[idx.take(o)] = rank >= count.take(s_sorted) // 2
