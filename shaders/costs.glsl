// Per-pixel costs of the scoring engine; shared by cost.frag (mipmap reduction) and
// reduce.comp (compute reduction) so both paths compute exactly the same numbers.
// The CPU twin of every function here is in gltrack/render/reference.py.
//
// Channels of the returned vec4:  x = depth cost, y = silhouette XOR count,
//                                 z = appearance consistent-pixel count, w = custom cost.
// Enabled by #defines: CH_DEPTH, CH_DEPTH_SMOOTH, CH_SILHOUETTE, CH_APPEARANCE, CH_CUSTOM.
// CH_MODEL (never with CH_DEPTH*) puts the model's unblocked pixel count |M \ B| in x: with the
// XOR count and the foreground area it gives the silhouette IoU of a pose.

uniform sampler2D model_z;    // grid texture: camera z of the model, 0 = no model
uniform sampler2D model_tri;  // grid texture: .g = 1 + triangle id (a float), 0 = no model
uniform sampler2D obs_z;      // tile-sized: observed depth in metres, 0 = no observation
uniform sampler2D obs_mask;   // tile-sized: r = foreground, g = blocked (Bandouch's I_B)
uniform usampler2D obs_bits;  // tile-sized: HLS bitmasks of the observed colour (h, l, s)
uniform usampler2D tri_bits;  // 1024 wide: HLS bitmasks of each triangle's colour cluster
uniform int tile;
// depth_params: smoothstep scale (m), cost when only the model is present, cost when only the
// observation is present, neighbour penalty of the smoothed likelihood.
uniform vec4 depth_params;

float depth_pixel(float zo, float zm) {
    bool o = zo > 0.0;
    bool m = zm > 0.0;
    if (o && m) return smoothstep(0.0, depth_params.x, abs(zo - zm));
    if (m) return depth_params.y;
    if (o) return depth_params.z;
    return 0.0;
}

#ifdef CH_CUSTOM
#include "custom_cost.glsl"
#endif

vec4 pixel_costs(ivec2 p) {
    // tile is a power of two: a mask, not p % tile, because integer division has no SIMD
    // form on a CPU (llvmpipe does it lane by lane)
    ivec2 local = p & (tile - 1);
    vec4 c = vec4(0.0);
#if defined(CH_DEPTH) || defined(CH_DEPTH_SMOOTH)
    float zo = texelFetch(obs_z, local, 0).r;
#ifdef CH_DEPTH_SMOOTH
    // Ganapathi's smoothed likelihood: best model pixel in the 3x3 neighbourhood (inside the tile),
    // paying a constant penalty for not being the pixel itself.
    float best = depth_pixel(zo, texelFetch(model_z, p, 0).r);
    // Costs are never negative, so a pixel whose own cost is 0 (nothing seen and no model: most
    // of a tile) cannot do better: skip its neighbours. Why: the neighbours are 8 of the 10
    // texture reads of a pixel, and the reduction is a third of a software renderer's time.
    if (best > 0.0) {
        for (int dy = -1; dy <= 1; ++dy) {
            for (int dx = -1; dx <= 1; ++dx) {
                ivec2 q = local + ivec2(dx, dy);
                if ((dx == 0 && dy == 0) || any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, ivec2(tile))))
                    continue;
                best = min(best, depth_pixel(zo, texelFetch(model_z, p + ivec2(dx, dy), 0).r) + depth_params.w);
            }
        }
    }
    c.x = best;
#else
    c.x = depth_pixel(zo, texelFetch(model_z, p, 0).r);
#endif
#endif
#if defined(CH_SILHOUETTE) || defined(CH_APPEARANCE) || defined(CH_MODEL)
    vec2 fb = texelFetch(obs_mask, local, 0).rg;
    bool blocked = fb.g > 0.5;
#endif
#ifdef CH_APPEARANCE
    // model_z and model_tri are one RG32F texture when triangle ids are drawn: one fetch for both
    vec2 model = texelFetch(model_tri, p, 0).rg;
#endif
#ifdef CH_SILHOUETTE
#ifdef CH_APPEARANCE
    bool model_on = model.r > 0.0;
#else
    bool model_on = texelFetch(model_z, p, 0).r > 0.0;
#endif
    bool fg = fb.r > 0.5;
    c.y = (model_on != fg && !blocked) ? 1.0 : 0.0;
#endif
#ifdef CH_MODEL
    c.x = (texelFetch(model_z, p, 0).r > 0.0 && !blocked) ? 1.0 : 0.0;
#endif
#ifdef CH_APPEARANCE
    int tri = int(model.g) - 1;
    if (tri >= 0 && !blocked) {
        uvec3 ob = texelFetch(obs_bits, local, 0).rgb;
        uvec3 tb = texelFetch(tri_bits, ivec2(tri & 1023, tri >> 10), 0).rgb;
        c.z = all(notEqual(ob & tb, uvec3(0u))) ? 1.0 : 0.0;
    }
#endif
#ifdef CH_CUSTOM
    c.w = custom_cost(p, local);
#endif
    return c;
}
