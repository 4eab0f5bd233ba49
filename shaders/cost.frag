#version 330 core
// Per-pixel costs into an RGBA32F grid texture, averaged per tile by the mipmap chain.
#include "costs.glsl"
out vec4 out_cost;

void main() {
    out_cost = pixel_costs(ivec2(gl_FragCoord.xy));
}
