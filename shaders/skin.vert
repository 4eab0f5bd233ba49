#version 330 core
// Linear-blend skinning of candidate gl_InstanceID, drawn into its tile of the grid.
#include "skinning.glsl"
#include "tile_place.glsl"

in vec3 in_pos;       // rest-pose position, metres
in ivec4 in_joints;   // up to four bone indices
in vec4 in_weights;   // their weights (sum 1)

void main() {
    place_in_tile(skin_vertex(in_pos, in_joints, in_weights, gl_InstanceID), gl_InstanceID);
}
