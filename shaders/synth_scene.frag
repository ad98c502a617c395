#version 330 core
// Shades a synthetic scene (triplanar textures, point lights) and stores, besides the colour,
// the plane of the visible surface in the panorama camera frame: (n, c) with n.x = c. The ERP
// pass intersects each pixel's exact ray with that plane, so depth is exact, not texel-snapped.
uniform sampler2DArray u_textures;
uniform vec3 u_cam_pos;
uniform mat3 u_world_to_cam;
uniform int u_num_lights;
uniform vec3 u_light_pos[8];
uniform vec3 u_light_color[8];
uniform vec3 u_ambient;

in vec3 v_world;
in vec3 v_normal;
in vec3 v_cam;
flat in vec4 v_mat;
flat in vec3 v_tint;

layout(location = 0) out vec4 out_color;
layout(location = 1) out vec4 out_plane;

vec3 triplanar(vec3 p, vec3 n) {
    vec2 off = v_mat.zw;
    float layer = v_mat.x;
    vec3 q = p / v_mat.y;
    vec3 a = abs(n);
    // Walls and boxes are axis-aligned: one fetch instead of three (a third of the cost).
    if (a.x > 0.999) return texture(u_textures, vec3(q.zy + off, layer)).rgb;
    if (a.y > 0.999) return texture(u_textures, vec3(q.xz + off, layer)).rgb;
    if (a.z > 0.999) return texture(u_textures, vec3(q.xy + off, layer)).rgb;
    vec3 w = pow(a, vec3(4.0));
    w /= (w.x + w.y + w.z);
    vec3 cx = texture(u_textures, vec3(q.zy + off, layer)).rgb;
    vec3 cy = texture(u_textures, vec3(q.xz + off, layer)).rgb;
    vec3 cz = texture(u_textures, vec3(q.xy + off, layer)).rgb;
    return cx * w.x + cy * w.y + cz * w.z;
}

void main() {
    vec3 n = normalize(v_normal);
    vec3 to_cam = u_cam_pos - v_world;
    if (dot(n, to_cam) < 0.0) n = -n;  // two-sided: walls are seen from inside and outside
    vec3 albedo = v_tint * triplanar(v_world, n);
    vec3 light = u_ambient * (0.75 + 0.25 * n.y);  // a little more ambient from above
    for (int i = 0; i < u_num_lights; ++i) {
        vec3 l = u_light_pos[i] - v_world;
        float dist2 = dot(l, l);
        float lambert = max(dot(n, l * inversesqrt(dist2)), 0.0);
        light += u_light_color[i] * lambert / (1.0 + 0.15 * dist2);
    }
    vec3 c = albedo * light;
    c = c / (1.0 + 0.25 * c);  // soft shoulder instead of a hard clip on bright spots
    out_color = vec4(clamp(c, 0.0, 1.0), 1.0);
    vec3 n_cam = normalize(u_world_to_cam * n);
    out_plane = vec4(n_cam, dot(n_cam, v_cam));
}
