#version 330 core
// Writes the metric depth (the depth buffer is only used for the z-test: its precision is not
// enough for a depth likelihood) and, with WITH_TRI, 1 + the id of the triangle seen at the pixel
// (0 = none). The integer output is compiled in only when a cost needs it: on software GL it
// costs ~40 % of the render time.
in float v_z;
layout(location = 0) out float out_z;
#ifdef WITH_TRI
layout(location = 1) out int out_tri;
#endif

void main() {
    out_z = v_z;
#ifdef WITH_TRI
    out_tri = gl_PrimitiveID + 1;
#endif
}
