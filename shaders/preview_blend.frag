#version 330 core
// Blends the sources' warped layers: per pixel the nearest surface wins, and every source
// that sees that same surface (distance within u_tolerance) contributes, weighted by its
// closeness to the target. Output alpha is 1 where some source saw the pixel, 0 elsewhere
// (a hole, filled by the push-pull passes). VIEWS (the number of layers) is defined at
// compile time, so the loops unroll and the layers stay in registers.
// DIST = 1: distances from the depth buffer (24 bits), the visible one written to out_dist.
// DIST = 0: distances from the layers' alpha (8-bit log scale, steps of under 3 %: enough to
// compare surfaces at u_tolerance, at half the cost: depth reads are slow on llvmpipe).
// GEO = 1: the layers hold the direction in which each source saw the surface and its log
// distance (preview_mesh.frag), and the colours are read from the sources here, once per pixel
// and source rather than once per drawn fragment.
uniform sampler2D u_layers;       // the sources' layers side by side: rgb, log distance
#if GEO
uniform sampler2DArray u_images;  // the source panoramas, repeating in u
uniform float u_source[VIEWS];    // each layer's source in u_images
#include "erp_uv.glsl"
#endif
uniform sampler2D u_depth;        // their depth buffer: distance / u_far (1: nothing drawn)
uniform float u_far;
uniform float u_weights[VIEWS];   // closeness of each drawn source to the target
uniform float u_tolerance;        // relative (DIST = 1) or on the log scale (DIST = 0)
uniform int u_width;              // width of one layer
layout(location = 0) out vec4 out_color;
#if DIST
layout(location = 1) out float out_dist;
#endif

void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    float best = 1e30;
    vec4 c[VIEWS];  // rgb, and the distance in alpha (0: nothing drawn)
    for (int j = 0; j < VIEWS; ++j) {
        ivec2 at = ivec2(px.x + j * u_width, px.y);
        c[j] = texelFetch(u_layers, at, 0);
#if GEO
        vec3 d = c[j].xyz;
        c[j] = dot(d, d) > 0.25
            ? vec4(texture(u_images, vec3(erp_uv(d), u_source[j])).rgb, c[j].w)
            : vec4(0.0);
#endif
#if DIST
        float z = texelFetch(u_depth, at, 0).r;
        c[j].a = z < 1.0 ? z * u_far : 0.0;
#endif
        if (c[j].a > 0.0) best = min(best, c[j].a);
    }
    vec3 acc = vec3(0.0);
    float wsum = 0.0;
#if DIST
    float limit = best * (1.0 + u_tolerance);
#else
    float limit = best + u_tolerance;
#endif
    for (int j = 0; j < VIEWS; ++j) {
        float k = (c[j].a > 0.0 && c[j].a <= limit) ? u_weights[j] : 0.0;
        acc += k * c[j].rgb;
        wsum += k;
    }
    bool seen = wsum > 0.0;
    out_color = seen ? vec4(acc / wsum, 1.0) : vec4(0.0);
#if DIST
    out_dist = seen ? best : 0.0;
#endif
}
