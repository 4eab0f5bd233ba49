#version 430 core
// Forward kinematics on the GPU: the pose parameters of every candidate of a batch -> the rows
// of its 3x4 linear-blend skinning matrices in the bones texture (what skin.vert and skin.comp
// read). One invocation per candidate walks the joints in topological order; the CPU twin is
// gltrack.body.kinematics.Kinematics.skinning_matrices (float64 there, float32 here).
// N_JOINTS is defined by the engine.
layout(local_size_x = 64) in;

struct Joint {
    ivec4 parent_cols;  // x: parent joint (-1 for the root); yzw: parameter column of each Euler
                        //    slot, first letter first (n_params = a locked axis, angle 0)
    ivec4 axes;         // xyz: axis (0 = x, 1 = y, 2 = z) of each Euler slot
    vec4 offset;        // xyz: joint position in its parent's frame at rest, metres
    vec4 rest;          // xyz: joint position in the world at rest, metres
};
layout(std430, binding = 5) readonly buffer Joints { Joint joints[]; };
layout(std430, binding = 6) readonly buffer Params { float params[]; };  // [cand * n_params + k]
layout(rgba32f, binding = 0) writeonly uniform image2D bones_out;  // 3 texels per bone, row = cand
uniform int n_params;
uniform int n_candidates;

mat3 elementary(int axis, float a) {
    // R_axis(a) (right-handed, as gltrack.body.kinematics.euler_to_matrix); columns given
    float c = cos(a), s = sin(a);
    if (axis == 0) return mat3(1.0, 0.0, 0.0,  0.0, c, s,  0.0, -s, c);
    if (axis == 1) return mat3(c, 0.0, -s,  0.0, 1.0, 0.0,  s, 0.0, c);
    return mat3(c, s, 0.0,  -s, c, 0.0,  0.0, 0.0, 1.0);
}

void main() {
    int cand = int(gl_GlobalInvocationID.x);
    if (cand >= n_candidates) return;
    int base = cand * n_params;
    mat3 Rw[N_JOINTS];
    vec3 Tw[N_JOINTS];
    for (int j = 0; j < N_JOINTS; ++j) {
        Joint J = joints[j];
        // R = E(first) E(second) E(third): the last letter is applied first
        mat3 L = mat3(1.0);
        for (int li = 0; li < 3; ++li) {
            int col = J.parent_cols[li + 1];
            float a = col < n_params ? params[base + col] : 0.0;
            L = L * elementary(J.axes[li], a);
        }
        int p = J.parent_cols.x;
        if (p < 0) {
            Rw[j] = L;
            Tw[j] = vec3(params[base], params[base + 1], params[base + 2]);
        } else {
            Rw[j] = Rw[p] * L;
            Tw[j] = Tw[p] + Rw[p] * J.offset.xyz;
        }
        vec3 t = Tw[j] - Rw[j] * J.rest.xyz;
        for (int r = 0; r < 3; ++r)  // row r of [R | t]; GLSL matrices are indexed [column][row]
            imageStore(bones_out, ivec2(3 * j + r, cand), vec4(Rw[j][0][r], Rw[j][1][r], Rw[j][2][r], t[r]));
    }
}
