#version 330 core
// Writes the metric depth (the depth buffer is only used for the z-test: its precision is not
// enough for a depth likelihood) and 1 + the id of the triangle seen at the pixel (0 = none).
in float v_z;
layout(location = 0) out float out_z;
layout(location = 1) out int out_tri;

void main() {
    out_z = v_z;
    out_tri = gl_PrimitiveID + 1;
}
