#version 330 core
// Writes the metric depth (the depth buffer is only used for the z-test: its precision is not
// enough for a depth likelihood) and, with WITH_TRI, 1 + the id of the triangle seen at the pixel
// (0 = none) as a float beside it in one RG32F attachment (exact for ids below 2^24). The id is
// compiled in only when a cost needs it.
in float v_z;
#ifdef TILE_CLIP_FRAGMENT
// The tile clip done here instead of by clip distances: a fragment outside its candidate's tile
// is dropped (the hardware still clips at the grid's border and the near and far planes).
flat in ivec2 v_tile;
uniform int tile;
#endif
#ifdef WITH_TRI
layout(location = 0) out vec2 out_zt;
#else
layout(location = 0) out float out_z;
#endif

void main() {
#ifdef TILE_CLIP_FRAGMENT
    if (ivec2(gl_FragCoord.xy) / tile != v_tile) discard;
#endif
#ifdef WITH_TRI
    out_zt = vec2(v_z, float(gl_PrimitiveID + 1));
#else
    out_z = v_z;
#endif
}
