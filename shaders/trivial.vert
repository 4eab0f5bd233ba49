#version 330 core
// Throughput bound: the same instanced triangles with no skinning and no texture fetches.
in vec3 in_pos;
uniform mat4 view;
uniform mat4 proj;
uniform ivec2 grid;
void main() {
    vec4 c = proj * (view * vec4(in_pos, 1.0));
    int col = gl_InstanceID % grid.x;
    int row = gl_InstanceID / grid.x;
    c.x = (c.x + c.w * float(1 + 2 * col)) / float(grid.x) - c.w;
    c.y = (c.y + c.w * float(1 + 2 * row)) / float(grid.y) - c.w;
    gl_Position = c;
}
