"""The GPU byte layout of the BVH: two std430 storage buffers, uploaded verbatim.

This module is the one place that documents the layout; `shaders/glsl/include/bvh.glsl` mirrors it.

Nodes buffer (binding BVH_BINDING): an array of 64-byte nodes, node 0 is the root. A node holds the boxes of
*both* its children, so one fetch tests two boxes (the BVH_GPU idea from tinybvh, and Aila & Laine's layout).
Leaves are not nodes: a child slot that is a leaf points straight at its triangles, so leaves cost no fetch.

    offset  type      field    meaning
    0       vec3      lmin     left child box, min corner
    12      uint      left     left child word (below)
    16      vec3      lmax     left child box, max corner
    28      uint      right    right child word
    32      vec3      rmin     right child box, min corner
    44      uint      lcount   left child: number of triangles if it is a leaf, 0 if it is a node
    48      vec3      rmax     right child box, max corner
    60      uint      rcount   right child: number of triangles if it is a leaf, 0 if it is a node

    child word: bit 31 clear -> index of an interior node in this buffer;
                bit 31 set   -> a leaf; bits 0..30 = index of its first triangle in the triangle buffer,
                                its triangles are [first, first + count).
    A leaf with count 0 is an empty slot (only for meshes of 0 or 1 triangle); its box is inverted (min = +inf,
    max = -inf), and testing it is harmless: it holds no triangle.

    In GLSL: struct BvhNode { vec4 a, b, c, d; } with a = (lmin, left), b = (lmax, right), c = (rmin, lcount),
    d = (rmax, rcount); the uint fields are read with floatBitsToUint.

Triangles buffer (binding BVH_BINDING + 1): 48 bytes per triangle, in leaf order (slot i is original triangle
prim_ids[i]):

    offset  type      field    meaning
    0       vec3      v0       first vertex (float32, bitwise as given after the float32 cast)
    12      int       prim     original triangle index (read with floatBitsToInt)
    16      vec3      v1       second vertex
    28      uint      pad1     0, or 1 + the triangle's alpha record (alpha-tested materials: the renderer's
                               shadow and AO passes, shaders/glsl/include/alpha.glsl)
    32      vec3      v2       third vertex
    44      uint      pad      0

    The raw vertices are stored, not (v0, e1, e2): the watertight test needs every shared vertex to be bitwise the
    same in all the triangles that use it, which edges rebuilt as v0 + e1 would not be. Degenerate triangles
    (zero area) are stored with v1 = v2 = v0, which the intersection test rejects exactly (its determinant is 0).

Nodes are numbered depth first (pre-order): the root is node 0, a node's left child, if it is a node, is the next
node (index + 1), and its right child comes after the whole left subtree, so every subtree occupies one contiguous
range of indices (cache locality for the traversal). The tree's depth (leaves at depth <= max_depth, root at 0) is
capped at build time so that the GLSL stack (BVH_STACK_SIZE entries) cannot overflow: the traversal pushes at most
depth - 1 entries.
"""

from __future__ import annotations

import numpy as np

#: Bit 31 of a child word marks a leaf.
LEAF_BIT = np.uint32(0x80000000)

NODE_DTYPE = np.dtype(
    [
        ("lmin", "<f4", (3,)),
        ("left", "<u4"),
        ("lmax", "<f4", (3,)),
        ("right", "<u4"),
        ("rmin", "<f4", (3,)),
        ("lcount", "<u4"),
        ("rmax", "<f4", (3,)),
        ("rcount", "<u4"),
    ]
)
assert NODE_DTYPE.itemsize == 64

TRI_DTYPE = np.dtype(
    [
        ("v0", "<f4", (3,)),
        ("prim", "<i4"),
        ("v1", "<f4", (3,)),
        ("pad1", "<u4"),
        ("v2", "<f4", (3,)),
        ("pad2", "<u4"),
    ]
)
assert TRI_DTYPE.itemsize == 48

NODE_BYTES = NODE_DTYPE.itemsize
TRI_BYTES = TRI_DTYPE.itemsize

# ---- the compressed node (CNODE), 32 bytes: made from the nodes above by engine/bvh/compress.py ----------------
# Used on CPU devices (bvh.glsl's BVH_COMPRESSED): half the bytes and texel fetches per node step, and two nodes
# per 64-byte cache line (a node and its left child share one every other time, pre-order).
# Same tree, same node numbering, same triangle buffer; 8 uint32 (2 texels) per node:
#
#     word  field
#     0     ox | ex      x axis: origin (float32 bits, low 8 mantissa bits 0) | exponent byte ex (bits 0..7)
#     1     oy | ey      y axis
#     2     oz | ez      z axis
#     3     left         child word (below)
#     4     qx           x axis: left lo (bits 0..7), left hi (8..15), right lo (16..23), right hi (24..31)
#     5     qy           y axis, same
#     6     qz           z axis, same
#     7     right        child word
#
#     decoded plane = origin + float(q) * 2^(e - 127), in float32: q * 2^k is exact, so there is one rounding, which
#     compress.py checks (and steps q outwards where needed): a decoded box always contains the builder's box.
#     origin is the nodes' box min rounded down (the low mantissa bits hold e); e is the smallest exponent with
#     255 * 2^(e-127) >= box max - origin (raised where rounding needs it). An empty slot decodes to a point.
#     child word: bit 31 clear -> interior node index; bit 31 set -> leaf: count in bits 27..30, first triangle in
#                 bits 0..26 (so leaves of <= 15 triangles and <= 2^27 triangles; otherwise the 64-byte nodes
#                 stay: compress_nodes returns None).
CNODE_WORDS = 8
CNODE_BYTES = 32
CNODE_COUNT_SHIFT = 27
CNODE_COUNT_BITS = 4
CNODE_FIRST_MASK = (1 << CNODE_COUNT_SHIFT) - 1
