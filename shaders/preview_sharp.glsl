// The sharp preview: the preview's colours at a finer resolution than its geometry was drawn
// at ("deferred colour"), shared by preview_sharp.frag (a pass of its own) and display.frag
// (SHARP = 1: computed as the viewer shows it, one full-resolution pass fewer).
// At ERP coordinates uv, each source's layer (GEO = 1 in preview_mesh.frag) is sampled
// bilinearly for the direction in which that source saw the surface and the surface's log
// distance, and the source panorama is read in that direction at its own full resolution:
// geometry at the layers' resolution, colour at the output's, so the texture detail that a
// coarser draw blurs comes back. Blending follows preview_blend.frag (the nearest surface, the
// sources within u_tolerance of it, weighted by closeness); what no source saw takes the
// push-pull-filled preview at the layers' resolution (u_filled). An undrawn texel is all
// zeros, so the length of a bilinear sample's direction is the fraction of its footprint that
// was drawn (its coverage). VIEWS (the number of layers) is defined at compile time.
uniform sampler2D u_geo;          // the layers side by side: direction xyz, log distance
uniform sampler2DArray u_images;  // the source panoramas, repeating in u
uniform sampler2D u_filled;       // the filled preview at the layers' rows
uniform float u_weights[VIEWS];   // closeness of each drawn source to the target
uniform float u_source[VIEWS];    // each layer's source in u_images
uniform float u_tolerance;        // on the log-distance scale
uniform vec2 u_layer;             // one layer's size in texels (width, height)

#include "erp_uv.glsl"

vec3 sharp_preview(vec2 uv) {
    // Within a layer's own strip: clamp half a texel from the strip's edges.
    float x = clamp(uv.x * u_layer.x, 0.5, u_layer.x - 0.5);
    float total = u_layer.x * float(VIEWS);
    vec4 g[VIEWS];  // unit direction, log distance
    float cover[VIEWS];
    float best = 1e30;
    for (int j = 0; j < VIEWS; ++j) {
        vec4 s = texture(u_geo, vec2((x + float(j) * u_layer.x) / total, uv.y));
        cover[j] = length(s.xyz);
        g[j] = s / max(cover[j], 1e-3);
        if (cover[j] > 0.25) best = min(best, g[j].w);
    }
    vec3 acc = vec3(0.0);
    float wsum = 0.0;
    float seen = 0.0;
    for (int j = 0; j < VIEWS; ++j) {
        bool use = cover[j] > 0.25 && g[j].w <= best + u_tolerance;
        float k = use ? u_weights[j] * cover[j] : 0.0;
        acc += k * texture(u_images, vec3(erp_uv(g[j].xyz), u_source[j])).rgb;
        wsum += k;
        seen = max(seen, use ? cover[j] : 0.0);
    }
    vec3 filled = texture(u_filled, uv).rgb;
    vec3 sharp = wsum > 0.0 ? acc / wsum : filled;
    return mix(filled, sharp, clamp(seen, 0.0, 1.0));
}
