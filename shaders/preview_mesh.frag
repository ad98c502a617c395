#version 330 core
uniform sampler2D u_image;  // the source panorama, repeating in u
in vec2 v_uv;
layout(location = 0) out vec4 out_color;  // rgb (the distance goes to the depth buffer)

void main() {
    out_color = vec4(texture(u_image, v_uv).rgb, 1.0);
}
