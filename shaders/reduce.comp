#version 430 core
// One work group per tile: evaluate the per-pixel costs and sum them in shared memory.
// Two group shapes (the engine's reduce_group, chosen per device): the default, 16x16
// invocations summed as a tree, suits a GPU; NARROW_GROUP, 8x8 invocations whose partial sums
// one invocation adds up after a single barrier, suits a software renderer, where every barrier
// switches each invocation's coroutine (llvmpipe: the reduction in 0.5-0.75x the time).
// Each camera of a call writes its own slice of the buffer (from index `base`), so the engine
// reads all cameras' sums back once, after the last camera, instead of once per camera.
#include "costs.glsl"
#ifdef NARROW_GROUP
#define LOCAL 8
#else
#define LOCAL 16
#endif
layout(local_size_x = LOCAL, local_size_y = LOCAL) in;
layout(std430, binding = 0) buffer Sums { vec4 sums[]; };
uniform ivec2 grid;
uniform int base;  // first slot of this camera's slice of sums
shared vec4 part[LOCAL * LOCAL];

void main() {
    ivec2 t = ivec2(gl_WorkGroupID.xy);
    ivec2 origin = t * tile;
    uint lid = gl_LocalInvocationIndex;
    vec4 acc = vec4(0.0);
    for (int y = int(gl_LocalInvocationID.y); y < tile; y += LOCAL)
        for (int x = int(gl_LocalInvocationID.x); x < tile; x += LOCAL)
            acc += pixel_costs(origin + ivec2(x, y));
    part[lid] = acc;
    barrier();
#ifdef NARROW_GROUP
    if (lid == 0u) {
        vec4 s = vec4(0.0);
        for (uint i = 0u; i < uint(LOCAL * LOCAL); ++i) s += part[i];
        sums[base + t.y * grid.x + t.x] = s;
    }
#else
    for (uint s = uint(LOCAL * LOCAL) / 2u; s > 0u; s >>= 1u) {
        if (lid < s) part[lid] += part[lid + s];
        barrier();
    }
    if (lid == 0u) sums[base + t.y * grid.x + t.x] = part[0];
#endif
}
