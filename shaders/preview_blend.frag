#version 330 core
// Blends the sources' warped layers: per pixel the nearest surface wins, and every source
// that sees that same surface (distance within u_tolerance) contributes, weighted by its
// closeness to the target. Output alpha is 1 where some source saw the pixel, 0 elsewhere
// (a hole, filled by the next pass).
uniform sampler2D u_layers;       // the sources' layers side by side: rgb + distance (0: none)
uniform int u_views;
uniform float u_weights[16];      // closeness of each drawn source to the target
uniform float u_tolerance;
uniform vec2 u_size;              // (W, H)
layout(location = 0) out vec4 out_color;
layout(location = 1) out float out_dist;

void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    int w = int(u_size.x);
    float best = 1e30;
    vec4 c[16];
    for (int j = 0; j < u_views; ++j) {
        c[j] = texelFetch(u_layers, ivec2(px.x + j * w, px.y), 0);
        if (c[j].a > 0.0) best = min(best, c[j].a);
    }
    vec3 acc = vec3(0.0);
    float wsum = 0.0;
    for (int j = 0; j < u_views; ++j) {
        float k = (c[j].a > 0.0 && c[j].a <= best * (1.0 + u_tolerance)) ? u_weights[j] : 0.0;
        acc += k * c[j].rgb;
        wsum += k;
    }
    bool seen = wsum > 0.0;
    out_color = seen ? vec4(acc / wsum, 1.0) : vec4(0.0);
    out_dist = seen ? best : 0.0;
}
