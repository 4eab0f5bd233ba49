#version 330 core
// Linear-blend skinning of candidate gl_InstanceID, drawn into tile (col, row) of a power-of-two grid.
// Camera convention: `view` maps world to OpenCV camera coordinates and `proj` is
// gltrack.camera.Camera.gl_projection, so framebuffer row r of a tile holds image row r.

in vec3 in_pos;       // rest-pose position, metres
in ivec4 in_joints;   // up to four bone indices
in vec4 in_weights;   // their weights (sum 1)

uniform sampler2D bones;  // RGBA32F, width 3*B, one row per candidate: rows of the 3x4 skinning matrices
uniform mat4 view;
uniform mat4 proj;
uniform ivec2 grid;       // tiles per row, tiles per column

out float v_z;            // camera-frame depth, metres (perspective-correct interpolation)

void main() {
    int cand = gl_InstanceID;
    vec4 p = vec4(in_pos, 1.0);
    vec3 s = vec3(0.0);
    for (int k = 0; k < 4; ++k) {
        float w = in_weights[k];
        if (w == 0.0) continue;
        int b = 3 * in_joints[k];
        s += w * vec3(dot(texelFetch(bones, ivec2(b, cand), 0), p),
                      dot(texelFetch(bones, ivec2(b + 1, cand), 0), p),
                      dot(texelFetch(bones, ivec2(b + 2, cand), 0), p));
    }
    vec4 cam = view * vec4(s, 1.0);
    v_z = cam.z;
    vec4 c = proj * cam;
    // Clip against the tile's own frustum so that no candidate can bleed into a neighbour.
    gl_ClipDistance[0] = c.w + c.x;
    gl_ClipDistance[1] = c.w - c.x;
    gl_ClipDistance[2] = c.w + c.y;
    gl_ClipDistance[3] = c.w - c.y;
    int col = cand % grid.x;
    int row = cand / grid.x;
    // Tile NDC [-1,1] -> grid NDC, written in clip space (multiplied through by w).
    c.x = (c.x + c.w * float(1 + 2 * col)) / float(grid.x) - c.w;
    c.y = (c.y + c.w * float(1 + 2 * row)) / float(grid.y) - c.w;
    gl_Position = c;
}
