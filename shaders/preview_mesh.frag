#version 330 core
// rgb, and the distance from the target in alpha on a log scale (1/255 at LOG_NEAR metres, 1 at
// u_far): what the blend compares when it needs no exact distance. The exact distance is in
// the depth buffer.
uniform sampler2D u_image;  // the source panorama, repeating in u
uniform float u_far;
in vec2 v_uv;
in float v_dist;
layout(location = 0) out vec4 out_color;

const float LOG_NEAR = 0.1;

void main() {
    float a = log(max(v_dist, LOG_NEAR) / LOG_NEAR) / log(u_far / LOG_NEAR);
    out_color = vec4(texture(u_image, v_uv).rgb, max(a, 1.0 / 255.0));
}
