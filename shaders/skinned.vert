#version 430 core
// Candidate gl_InstanceID's vertices as skin.comp left them, drawn into its tile of the grid.
#include "tile_place.glsl"
layout(std430, binding = 4) readonly buffer Skinned { vec4 skinned[]; }; // [cand * n + v]
uniform int n_vertices;

void main() {
    place_in_tile(skinned[gl_InstanceID * n_vertices + gl_VertexID].xyz, gl_InstanceID);
}
