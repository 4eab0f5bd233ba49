#version 430 core
// One work group per tile: evaluate the per-pixel costs and sum them in shared memory.
#include "costs.glsl"
#define LOCAL 16
layout(local_size_x = LOCAL, local_size_y = LOCAL) in;
layout(std430, binding = 0) buffer Sums { vec4 sums[]; };
uniform ivec2 grid;
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
    for (uint s = uint(LOCAL * LOCAL) / 2u; s > 0u; s >>= 1u) {
        if (lid < s) part[lid] += part[lid + s];
        barrier();
    }
    if (lid == 0u) sums[t.y * grid.x + t.x] = part[0];
}
