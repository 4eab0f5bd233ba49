// Linear-blend skinning of one rest-pose vertex for candidate `cand` (shared by skin.vert and
// skin.comp). `bones` is RGBA32F, width 3*B, one row per candidate: the rows of its 3x4 matrices.
uniform sampler2D bones;

vec3 skin_vertex(vec3 pos, ivec4 joints, vec4 weights, int cand) {
    vec4 p = vec4(pos, 1.0);
    vec3 s = vec3(0.0);
    for (int k = 0; k < 4; ++k) {
        float w = weights[k];
        if (w == 0.0) continue;
        int b = 3 * joints[k];
        s += w * vec3(dot(texelFetch(bones, ivec2(b, cand), 0), p),
                      dot(texelFetch(bones, ivec2(b + 1, cand), 0), p),
                      dot(texelFetch(bones, ivec2(b + 2, cand), 0), p));
    }
    return s;
}
