#version 330 core
// rgb, and the distance from the target in alpha on a log scale (see preview_mesh.vert): what
// the blend compares when it needs no exact distance. The exact distance is in the depth buffer.
uniform sampler2D u_image;  // the source panorama, repeating in u
in vec2 v_uv;
in float v_log_dist;
layout(location = 0) out vec4 out_color;

void main() {
    out_color = vec4(texture(u_image, v_uv).rgb, max(v_log_dist, 1.0 / 255.0));
}
