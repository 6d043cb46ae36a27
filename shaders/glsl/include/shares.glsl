// shares.glsl: the order in which a dispatch's workgroups take their work, for CPU devices.
//
// llvmpipe 22.3 splits a dispatch's workgroups into one contiguous share per worker thread (lp_cs_tpool:
// iter_per_thread = groups / threads), and the dispatch lasts as long as its slowest share. Work in image order
// puts the top of the image in one share and the bottom in the other (and the rays' work is seldom even between
// the halves). share_block maps workgroup w of n, in shares of n / shares, to the work block it takes:
// workgroup p of share s takes block p * shares + (s + p) % shares, so that every share takes one block of every
// `shares` consecutive ones (rotating, so that no period in the blocks' cost can line up with a share) and
// neighbouring workgroups of a share stay neighbours in the image. A permutation of [0, n) for any shares >= 1;
// shares = 1 (GPUs) is the identity, and a share count other than the device's is only slower, never wrong.
#ifndef SHARES_GLSL
#define SHARES_GLSL
uint share_block(uint w, uint n, uint shares) {
    if (shares <= 1u) {
        return w;  // (a specialization constant of 1, as on GPUs, folds the rest away)
    }
    uint t = shares;
    uint q = n / t;
    if (w >= t * q) {
        return w;  // the last n % shares workgroups, which llvmpipe hands out one by one
    }
    uint p = w % q;
    return p * t + (w / q + p) % t;
}

// The workgroup this one stands for, in that order, over a whole 1D, 2D or 3D dispatch (llvmpipe counts its
// workgroups x fastest, then y, then z), and the invocation's global id in it: what gl_GlobalInvocationID would be.
uvec3 share_group(uint shares) {
    uvec3 n = gl_NumWorkGroups;
    uint w = (gl_WorkGroupID.z * n.y + gl_WorkGroupID.y) * n.x + gl_WorkGroupID.x;
    uint b = share_block(w, n.x * n.y * n.z, shares);
    return uvec3(b % n.x, (b / n.x) % n.y, b / (n.x * n.y));
}
uvec3 share_invocation(uint shares, uvec3 workgroup_size) {
    if (shares <= 1u) {
        return gl_GlobalInvocationID;
    }
    return share_group(shares) * workgroup_size + gl_LocalInvocationID;
}
#endif
