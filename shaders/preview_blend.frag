#version 330 core
// Blends the sources' warped layers: per pixel the nearest surface wins, and every source
// that sees that same surface (distance within u_tolerance) contributes, weighted by its
// closeness to the target. Pixels no source saw (disocclusions, poles) take the farthest of a
// few neighbours found along eight directions: the background behind an edge.
uniform sampler2D u_layers;       // the sources' layers side by side: rgb + distance (0: none)
uniform int u_views;
uniform float u_weights[16];      // closeness of each source to the target
uniform float u_tolerance;
uniform vec2 u_size;              // (W, H)
layout(location = 0) out vec4 out_color;
layout(location = 1) out float out_dist;

vec4 blend_at(ivec2 px) {
    float best = 1e30;
    for (int j = 0; j < u_views; ++j) {
        float d = texelFetch(u_layers, ivec2(px.x + j * int(u_size.x), px.y), 0).a;
        if (d > 0.0) best = min(best, d);
    }
    if (best >= 1e30) return vec4(0.0);
    vec3 acc = vec3(0.0);
    float wsum = 0.0;
    for (int j = 0; j < u_views; ++j) {
        vec4 c = texelFetch(u_layers, ivec2(px.x + j * int(u_size.x), px.y), 0);
        if (c.a > 0.0 && c.a <= best * (1.0 + u_tolerance)) {
            acc += u_weights[j] * c.rgb;
            wsum += u_weights[j];
        }
    }
    return vec4(acc / wsum, best);
}

void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 c = blend_at(px);
    if (c.a <= 0.0) {
        int w = int(u_size.x);
        int h = int(u_size.y);
        for (int step = 1; step <= 16 && c.a <= 0.0; step *= 4) {
            for (int k = 0; k < 8; ++k) {
                ivec2 dir = ivec2(k == 0 || k == 4 || k == 5 ? 1 : (k == 1 || k == 6 || k == 7 ? -1 : 0),
                                  k == 2 || k == 4 || k == 6 ? 1 : (k == 3 || k == 5 || k == 7 ? -1 : 0));
                ivec2 q = px + dir * step;
                q.x = (q.x % w + w) % w;               // wrap across the seam
                q.y = clamp(q.y, 0, h - 1);
                vec4 n = blend_at(q);
                if (n.a > c.a) c = n;                  // the farthest neighbour found
            }
        }
    }
    out_color = vec4(c.rgb, 1.0);
    out_dist = c.a;
}
