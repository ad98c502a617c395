#version 330 core
// A source view's depth mesh: one vertex per depth pixel, already lifted to the world.
in vec3 in_pos;       // world position (metres)
in vec2 in_uv;        // source texture coordinate; u > 1 on the column that closes the seam
in float in_depth;    // the source's own spherical depth at this vertex (metres)
uniform mat4 u_w2c;   // target world -> camera
out vec3 v_cam;
out vec2 v_uv;
out float v_src_depth;

void main() {
    v_cam = (u_w2c * vec4(in_pos, 1.0)).xyz;
    v_uv = in_uv;
    v_src_depth = in_depth;
    gl_Position = vec4(0.0, 0.0, 0.0, 1.0);  // placed by the geometry shader
}
