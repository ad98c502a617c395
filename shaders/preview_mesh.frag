#version 330 core
uniform sampler2D u_image;  // the source panorama, repeating in u
in vec2 v_uv;
in float v_dist;
layout(location = 0) out vec4 out_color;  // rgb, and the distance from the target in alpha

void main() {
    out_color = vec4(texture(u_image, v_uv).rgb, v_dist);
}
