#version 430 core
// Skinning as a compute pass: every vertex of every candidate of a batch, once for all cameras,
// into a buffer that skinned.vert reads. A GPU runs compute on all its multiprocessors, while
// some (NVIDIA's H100 and H200) run vertex shaders on a few graphics-capable ones only.
#include "skinning.glsl"
layout(local_size_x = 64) in;
layout(std430, binding = 1) readonly buffer Rest { vec4 rest[]; };       // xyz, metres
layout(std430, binding = 2) readonly buffer Joints { ivec4 joints[]; };
layout(std430, binding = 3) readonly buffer Weights { vec4 weights[]; };
layout(std430, binding = 4) writeonly buffer Skinned { vec4 skinned[]; }; // [cand * n + v]
uniform int n_vertices;

void main() {
    int v = int(gl_GlobalInvocationID.x);
    int cand = int(gl_GlobalInvocationID.y);
    if (v >= n_vertices) return;
    skinned[cand * n_vertices + v] = vec4(skin_vertex(rest[v].xyz, joints[v], weights[v], cand), 1.0);
}
