"""What the passes of the build make, and its packing into GPU nodes.

`Record`: the interior nodes one pass makes. `Leaves`: the leaves, collected pass by pass (in each chunk group's own
loop, on its cache-sized data): the triangles of a pass's leaves are put in leaf order with a stable 16-bit radix
argsort. A leaf of a node binned without sampling (and not split at its median) takes its box from the statistics
(the union of the cells on its side, exactly the union of its triangles' boxes); the others reduce theirs with
np.minimum.at keyed by leaf. So leaf order and leaf boxes need no sort or scatter over the whole mesh. `finish`: the
interior nodes renumbered depth first (pre-order, see layout.py), with exact boxes and the SAH cost, packed as
NODE_DTYPE.

Boxes are carried as six float32 rows (min x, min y, min z, -max x, -max y, -max z) so that the union of boxes is a
single elementwise minimum.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import native
from .binning import half_area
from .layout import LEAF_BIT, NODE_DTYPE


@dataclass
class Record:
    """Interior nodes made together. child[k, side] indexes record rec[k, side], or is a leaf id where rec is -1."""

    child: np.ndarray  # (K, 2) int64
    rec: np.ndarray  # (K, 2) int64


class Leaves:
    """The leaves made so far, in id order, in batches (one per pass): the triangles of every leaf in leaf order
    (Morton order inside a leaf), and every leaf's size, depth and box ((L, 6) rows, six-row form)."""

    def __init__(self):
        self.tids: list[np.ndarray] = []
        self.sizes: list[np.ndarray] = []
        self.depths: list[np.ndarray] = []
        self.boxes: list[np.ndarray] = []

    def add(self, box, tids, leaf, sizes, depths, known=None):
        """A batch of len(sizes) leaves: triangles `tids` (increasing) of leaf `leaf` (0 .. len(sizes) - 1).
        known: (boxes (6, L) in six-row form, which of them are exact); the others are reduced from the triangles."""
        if known is None:
            lb = np.full((6, sizes.size), np.inf, dtype=np.float32)  # empty leaves keep the inverted box
            todo = None
        else:
            lb, have = known
            todo = ~have
            if todo.all():
                lb[:] = np.inf
                todo = None
            elif todo.any():
                lb[:, todo] = np.inf
            else:
                todo = False
        if tids.size:
            if todo is None:
                for r in range(6):
                    np.minimum.at(lb[r], leaf, box[r].take(tids))
            elif todo is not False:
                sel = np.flatnonzero(todo.take(leaf))
                t, lf = tids.take(sel), leaf.take(sel)
                for r in range(6):
                    np.minimum.at(lb[r], lf, box[r].take(t))
            tids = tids.take(_stable_order(leaf, sizes.size))
        lb = np.ascontiguousarray(lb.T)
        self.tids.append(tids)
        self.sizes.append(sizes)
        self.depths.append(depths)
        self.boxes.append(lb)

    def append(self, tids, sizes, depths, boxes):
        """A batch of leaves made elsewhere (native.grow): triangles already in leaf order, boxes (L, 6)."""
        self.tids.append(tids)
        self.sizes.append(sizes)
        self.depths.append(depths)
        self.boxes.append(boxes)

    def extend(self, other: "Leaves", t: np.ndarray) -> int:
        """Append the leaves of a sub-build whose triangle i is triangle t[i] here; returns how many."""
        self.tids.extend(t.take(x) for x in other.tids)
        self.sizes.extend(other.sizes)
        self.depths.extend(other.depths)
        self.boxes.extend(other.boxes)
        return sum(x.size for x in other.sizes)

    def arrays(self):
        """(slot -> sorted triangle index, sizes, depths, the batches' boxes (a list of (l, 6)))."""
        return np.concatenate(self.tids), np.concatenate(self.sizes), np.concatenate(self.depths), self.boxes


def finish(records, leaf_boxes, leaf_first, leaf_size, n_tri: int, widen: bool = False):
    """The packed nodes (NODE_DTYPE) in depth-first order, and the SAH cost.

    Records in order give the build's node ids (record 0 row 0 is the root; children always live in later
    records). Subtree sizes go bottom up and depth-first positions top down (pre-order: the left child at the
    parent + 1, the right child after the whole left subtree), one vector step per record; then one pass over the
    records in reverse makes the exact boxes (a node's box is the union of its children's) and writes every
    record's rows, packed, at their positions. leaf_boxes: the leaves' boxes, (l, 6) batches in leaf order.
    widen: the packed boxes are stepped outwards as builder._widen does (the SAH cost is of the exact boxes).
    In C where engine/native.py has its library (the same nodes; the SAH terms summed here as below).
    """
    base = np.concatenate([[0], np.cumsum([rc.child.shape[0] for rc in records])]).astype(np.int64)
    n_nodes = int(base[-1])
    in_c = native.finish(
        np.concatenate([rc.child for rc in records]),
        np.concatenate([rc.rec for rc in records]),
        np.diff(base),
        np.concatenate(leaf_boxes) if leaf_boxes else np.empty((0, 6), np.float32),
        leaf_first,
        leaf_size,
        widen,
    )
    if in_c is not None:
        out, root_box, terms = in_c
        sah = 0.0
        for r in range(len(records) - 1, -1, -1):  # (each record's terms summed as one array, as below)
            sah += float(terms[base[r] : base[r + 1]].sum())
        return _cost(out.view(NODE_DTYPE).reshape(n_nodes), root_box, sah, n_nodes, n_tri)
    # child node ids in build order; -1 (a leaf) reads the extra last entry of size / pos
    nids = [np.where(rc.rec >= 0, base.take(np.maximum(rc.rec, 0)) + rc.child, -1) for rc in records]
    size = np.empty(n_nodes + 1, dtype=np.int64)
    size[n_nodes] = 0
    for r in range(len(records) - 1, -1, -1):
        sz = size.take(nids[r])
        size[base[r] : base[r + 1]] = sz[:, 0] + sz[:, 1] + 1
    pos = np.empty(n_nodes + 1, dtype=np.int64)
    pos[0] = 0
    for r in range(len(records)):
        nid = nids[r]
        p = pos[base[r] : base[r + 1]] + 1
        pos[nid[:, 0]] = p  # leaves write the spare entry
        p += size.take(nid[:, 0])
        pos[nid[:, 1]] = p

    leaf_word = leaf_first.astype(np.uint32) | LEAF_BIT
    # the packed rows and the boxes are moved as whole records (void views): one copy per row
    out = np.empty((n_nodes, 16), dtype=np.float32)
    out_rows = out.view(_V64).reshape(n_nodes)
    # boxes of the nodes (build ids) and then of the leaves (row n_nodes + 1 + leaf id), one table for one gather
    box_of = np.empty((n_nodes + 1 + int(leaf_size.size), 6), dtype=np.float32)
    if leaf_boxes:
        np.concatenate(leaf_boxes, out=box_of[n_nodes + 1 :])
    box_rows = box_of.view(_V24).reshape(-1)
    node_box = box_of[: n_nodes + 1]
    sah = 0.0
    for r in range(len(records) - 1, -1, -1):
        rc, nid = records[r], nids[r]
        is_leaf = nid < 0
        lid = np.where(is_leaf, rc.child, 0)
        cb = box_rows.take(np.where(is_leaf, rc.child + (n_nodes + 1), nid)).view(np.float32).reshape(-1, 2, 6)
        node_box[base[r] : base[r + 1]] = np.minimum(cb[:, 0], cb[:, 1])
        blk = np.empty((nid.shape[0], 4, 4), dtype=np.float32)  # (lmin, left) (lmax, right) (rmin, lc) (rmax, rc)
        wb = _step_down(cb) if widen else cb
        blk[:, 0::2, :3] = wb[:, :, :3]
        np.negative(wb[:, :, 3:], out=blk[:, 1::2, :3])
        u = blk.view(np.uint32)
        u[:, 0:2, 3] = np.where(is_leaf, leaf_word.take(lid), pos.take(nid))
        wt = np.where(is_leaf, leaf_size.take(lid), 1)
        u[:, 2:4, 3] = np.where(is_leaf, wt, 0)
        out_rows[pos[base[r] : base[r + 1]]] = blk.reshape(-1, 16).view(_V64).reshape(-1)
        # SAH: every child slot's box is its child's box; leaves weigh their triangle count (empty ones nothing)
        with np.errstate(invalid="ignore", over="ignore"):
            area = half_area(cb.transpose(2, 0, 1)).astype(np.float64)
            sah += float(np.where(wt > 0, area * wt, 0.0).sum())
    return _cost(out.view(NODE_DTYPE).reshape(n_nodes), node_box[0], sah, n_nodes, n_tri)


def _cost(nodes, root_box, sah: float, n_nodes: int, n_tri: int):
    """(nodes, the SAH cost: (root area + the child slots' terms) / root area)."""
    if n_tri == 0:
        return nodes, 0.0
    with np.errstate(invalid="ignore", over="ignore"):
        a_root = float(half_area(root_box))
    if not a_root > 0:
        return nodes, float(n_nodes + n_tri)
    return nodes, (a_root + sah) / a_root


def _step_down(x: np.ndarray) -> np.ndarray:
    """np.nextafter(x, -inf) of the finite float32 values of x, the others as they are, by integer steps on the
    bits. In six-row form this widens a box by one float32 step on every side (its rows are min and -max)."""
    u = x.view(np.int32)
    out = np.where(u > 0, u - 1, u + 1)  # positive: towards zero; negative (and -0): away from it
    out[u == 0] = np.iinfo(np.int32).min + 1  # +0: the negative subnormal next to it
    keep = (u & 0x7F800000) == 0x7F800000  # inf, NaN
    if keep.any():
        out[keep] = u[keep]
    return out.view(np.float32)


_V64 = np.dtype((np.void, 64))  # a packed node
_V24 = np.dtype((np.void, 24))  # a box in six-row form


def _stable_order(key: np.ndarray, n_keys: int) -> np.ndarray:
    """Stable argsort of integer keys in [0, n_keys): numpy's radix sort of 16-bit keys, twice (LSD) for larger."""
    if n_keys <= 1 << 16:
        return np.argsort(key.astype(np.uint16), kind="stable")
    order = np.argsort((key & 0xFFFF).astype(np.uint16), kind="stable")
    hi = (key.take(order) >> 16).astype(np.uint16 if n_keys <= 1 << 32 else np.int64)
    return order.take(np.argsort(hi, kind="stable"))
