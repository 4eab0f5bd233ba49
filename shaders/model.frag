#version 330 core
// Writes the metric depth (the depth buffer is only used for the z-test: its precision is not
// enough for a depth likelihood) and, with WITH_TRI, 1 + the id of the triangle seen at the pixel
// (0 = none) as a float beside it in one RG32F attachment (exact for ids below 2^24). The id is
// compiled in only when a cost needs it. It comes from gl_PrimitiveID or, with TRI_FROM_VERTEX, from
// the triangle's provoking vertex (tile_place.glsl, drawn in the vertex layout of
// gltrack.render.provoking), whichever the device draws faster (choose_triangle_ids).
in float v_z;
#ifdef TILE_CLIP_FRAGMENT
// The tile clip done here instead of by clip distances: a fragment outside its candidate's tile
// is dropped (the hardware still clips at the grid's border and the near and far planes).
flat in ivec2 v_tile;
uniform int tile;
#endif
#ifdef TRI_FROM_VERTEX
flat in int v_tri;
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
#ifdef TRI_FROM_VERTEX
    out_zt = vec2(v_z, float(v_tri + 1));
#else
    out_zt = vec2(v_z, float(gl_PrimitiveID + 1));
#endif
#else
    out_z = v_z;
#endif
}
