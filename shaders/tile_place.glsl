// Projects a world point of candidate `cand` into its tile (col, row) of a power-of-two grid
// (shared by skin.vert and skinned.vert). Camera convention: `view` maps world to OpenCV camera
// coordinates and `proj` is gltrack.camera.Camera.gl_projection, so framebuffer row r of a tile
// holds image row r.
uniform mat4 view;
uniform mat4 proj;
uniform ivec2 grid;       // tiles per row, tiles per column

out float v_z;            // camera-frame depth, metres (perspective-correct interpolation)
#ifdef TILE_CLIP_FRAGMENT
flat out ivec2 v_tile;    // the candidate's tile (col, row): model.frag drops what falls outside
#endif
#ifdef TRI_FROM_VERTEX
// The triangle this vertex provokes (-1: none; gltrack.render.provoking). A flat output takes the
// provoking vertex's value, so the fragment shader gets the triangle's id without reading
// gl_PrimitiveID, which sends llvmpipe down a slow primitive-assembly path.
in int in_tri;
flat out int v_tri;
#endif

void place_in_tile(vec3 world, int cand) {
    vec4 cam = view * vec4(world, 1.0);
    v_z = cam.z;
#ifdef TRI_FROM_VERTEX
    v_tri = in_tri;
#endif
    vec4 c = proj * cam;
    int col = cand % grid.x;
    int row = cand / grid.x;
#ifdef TILE_CLIP_FRAGMENT
    v_tile = ivec2(col, row);
#else
    // Clip against the tile's own frustum so that no candidate can bleed into a neighbour.
    gl_ClipDistance[0] = c.w + c.x;
    gl_ClipDistance[1] = c.w - c.x;
    gl_ClipDistance[2] = c.w + c.y;
    gl_ClipDistance[3] = c.w - c.y;
#endif
    // Tile NDC [-1,1] -> grid NDC, written in clip space (multiplied through by w).
    c.x = (c.x + c.w * float(1 + 2 * col)) / float(grid.x) - c.w;
    c.y = (c.y + c.w * float(1 + 2 * row)) / float(grid.y) - c.w;
    gl_Position = c;
}
