#version 330 core
// Resamples a six-face cube atlas (faces side by side, each F x F, the face order and
// orientation of model/cubemap.py) into an equirectangular panorama. Row 0 of the output
// framebuffer is the top image row (latitude +90 deg), so read-back needs no flip.
uniform sampler2D u_color_atlas;   // alpha 0 where no triangle was drawn
uniform sampler2D u_plane_atlas;   // (n, c) per texel, camera frame
uniform mat3 u_face_rot[6];        // face camera -> panorama camera
uniform int u_face_size;
uniform vec2 u_erp_size;           // (W, H)
uniform float u_max_depth;

layout(location = 0) out vec4 out_color;
layout(location = 1) out float out_depth;

const float PI = 3.14159265358979;

void main() {
    float lon = 2.0 * PI * (gl_FragCoord.x / u_erp_size.x - 0.5);
    float lat = PI * (0.5 - gl_FragCoord.y / u_erp_size.y);
    vec3 d = vec3(cos(lat) * sin(lon), sin(lat), -cos(lat) * cos(lon));

    int face = 0;
    float best = -2.0;
    vec3 local = d;
    for (int k = 0; k < 6; ++k) {
        vec3 q = transpose(u_face_rot[k]) * d;
        if (-q.z > best) { best = -q.z; face = k; local = q; }
    }
    vec2 f = local.xy / -local.z;               // [-1, 1] on the face, y up
    float fs = float(u_face_size);
    vec2 px = clamp((f * 0.5 + 0.5) * fs, vec2(0.0), vec2(fs - 1e-3)); // texel units, y up

    // Bilinear colour by hand, within the face, skipping uncovered texels (alpha 0): clipping
    // of huge triangles at the camera plane can leave one-texel cracks between them.
    vec2 q = px - 0.5;
    ivec2 i0 = ivec2(floor(q));
    vec2 fr = q - vec2(i0);
    vec4 acc = vec4(0.0);
    float best_w = -1.0;
    ivec2 best_t = clamp(ivec2(floor(px)), ivec2(0), ivec2(u_face_size - 1));
    for (int j = 0; j < 2; ++j) {
        for (int i = 0; i < 2; ++i) {
            ivec2 t = clamp(i0 + ivec2(i, j), ivec2(0), ivec2(u_face_size - 1));
            vec4 c = texelFetch(u_color_atlas, ivec2(face * u_face_size + t.x, t.y), 0);
            float w = (i == 1 ? fr.x : 1.0 - fr.x) * (j == 1 ? fr.y : 1.0 - fr.y) * c.a;
            acc += vec4(c.rgb * w, w);
            if (w > best_w) { best_w = w; best_t = t; }
        }
    }
    out_color = vec4(acc.a > 0.0 ? acc.rgb / acc.a : vec3(0.0), 1.0);

    // Depth: exact intersection of this pixel's ray with the surface plane of the nearest
    // covered texel (the heaviest of the bilinear four).
    ivec2 ti = best_t;
    vec4 plane = texelFetch(u_plane_atlas, ivec2(face * u_face_size + ti.x, ti.y), 0);
    vec2 tc = (vec2(ti) + 0.5) / fs * 2.0 - 1.0;
    vec3 d_texel = normalize(u_face_rot[face] * vec3(tc, -1.0));
    float t_texel = plane.w / dot(plane.xyz, d_texel);
    float denom = dot(plane.xyz, d);
    float t = denom != 0.0 ? plane.w / denom : -1.0;
    // At a depth edge the nearest texel can belong to another surface whose plane this ray meets
    // far away or behind: then keep the texel's own distance. (On grazing walls the depth
    // legitimately changes a lot within one texel, so the bound is loose.)
    if (!(t > 0.0) || t > 2.0 * t_texel || t < 0.5 * t_texel) t = t_texel;
    out_depth = (t > 0.0 && t < u_max_depth) ? t : 0.0;
}
