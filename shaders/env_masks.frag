#version 330 core
// Bandouch 2009, eqs. 3-7: the implicit environment layers of one camera image, per pixel.
// CPU twin: gltrack.observe.environment.environment_masks_cpu (must stay bitwise equal).
//
// Paper convention: I_B = 1 where a pixel is processed, 0 where blocked.
//   I_F'  = AND(I_F, I_H)                      (5)  non-human colours leave the foreground
//   I_B'  = AND(I_B, NOT(DIFF(I_F, I_F')))     (6)  ... and are blocked
//   I_B'' = OR(I_B', I_F')                     (7)  human-coloured foreground is never blocked
//   fg    = AND(I_F', I_B'')                   (3)  (equals I_F', kept to follow the paper)

uniform usampler2D obs_packed; // camera-sized: bits 0-14 HLS voxel, bit 15 I_F, bit 16 occluder
uniform usampler2D human_lut; // 256 x 128: voxel v at (v % 256, v / 256), 1 = human colour
layout(location = 0) out uint out_masks; // bit 0 fg, bit 1 blocked (= NOT I_B''), bit 2 I_H

void main() {
    uint v = texelFetch(obs_packed, ivec2(gl_FragCoord.xy), 0).r;
    uint vox = v & 0x7FFFu;
    bool i_f = ((v >> 15) & 1u) != 0u;
    bool i_b = ((v >> 16) & 1u) == 0u;  // user polygons unset I_B
    bool i_h = texelFetch(human_lut, ivec2(int(vox & 255u), int(vox >> 8)), 0).r != 0u;
    bool i_f1 = i_f && i_h;
    bool i_b1 = i_b && !(i_f && !i_f1);
    bool i_b2 = i_b1 || i_f1;
    bool fg = i_f1 && i_b2;
    out_masks = (fg ? 1u : 0u) | (i_b2 ? 0u : 2u) | (i_h ? 4u : 0u);
}
