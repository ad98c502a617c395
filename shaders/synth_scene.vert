#version 330 core
// Synthetic scene: one cube face of a panorama camera. Positions are world metres.
uniform mat4 u_view_proj;   // world -> clip for this face
uniform vec3 u_cam_pos;     // panorama camera centre, world
uniform mat3 u_world_to_cam; // world -> panorama camera frame (rotation only)

in vec3 in_pos;
in vec3 in_normal;
in vec4 in_mat;   // texture layer, metres per texture tile, uv offset (2)
in vec3 in_tint;

out vec3 v_world;
out vec3 v_normal;
out vec3 v_cam;   // position relative to the camera, camera frame
flat out vec4 v_mat;
flat out vec3 v_tint;

void main() {
    v_world = in_pos;
    v_normal = in_normal;
    v_cam = u_world_to_cam * (in_pos - u_cam_pos);
    v_mat = in_mat;
    v_tint = in_tint;
    gl_Position = u_view_proj * vec4(in_pos, 1.0);
}
