// The diffuse GI's cells (engine/passes/gi.py): GI_CELL 2 (setting gi_resolution "half"): one traced pixel per 2x2
// block and frame, the block's pixels taken in turn over 4 frames (the first covered one from this frame's turn on,
// so a block that a silhouette or a metal crosses still traces a pixel); GI_CELL 1 ("full"): a cell per pixel.
// Cell (cx, cy) at index cy * cells.x + cx.
layout(constant_id = 40) const uint GI_CELL = 2u;
const uint GI_TURNS = GI_CELL * GI_CELL;   // the pixels a cell takes in turn
const ivec2 GI_TURN[4] = ivec2[](ivec2(0, 0), ivec2(1, 1), ivec2(1, 0), ivec2(0, 1));

uvec2 gi_cells(uint w, uint h) { return (uvec2(w, h) + GI_CELL - 1u) / GI_CELL; }

// The pixel of `cell` whose turn it is in frame `index` (clamped to the image), without coverage tests.
ivec2 gi_turn(ivec2 cell, uint index, uint k, uint w, uint h) {
    if (GI_CELL == 1u) return cell;
    return min(2 * cell + GI_TURN[(index + k) & 3u], ivec2(int(w) - 1, int(h) - 1));
}
