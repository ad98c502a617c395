#version 330 core
// Projects a source-mesh triangle into the target's equirectangular image. Row 0 of the
// framebuffer is the top row (latitude +90 deg), like the other ERP passes, so read-back needs
// no flip. Triangles that cross the seam (longitude +-180 deg) are drawn twice, shifted by one
// full turn, so each side gets its part; triangles spanning a depth discontinuity (the
// "stretched" triangles of a depth mesh) and triangles around the target's poles (longitude
// undefined) are dropped: other sources or the hole filling cover them.
layout(triangles) in;
layout(triangle_strip, max_vertices = 6) out;

in vec3 v_cam[];
in vec2 v_uv[];
in float v_src_depth[];
uniform float u_max_stretch;  // largest max/min source depth of a kept triangle
uniform float u_far;          // metres mapped to the far end of the depth buffer
out vec2 g_uv;
out float g_dist;

const float PI = 3.14159265358979;

void main() {
    float dmin = min(min(v_src_depth[0], v_src_depth[1]), v_src_depth[2]);
    float dmax = max(max(v_src_depth[0], v_src_depth[1]), v_src_depth[2]);
    if (dmin <= 0.0 || dmax > u_max_stretch * dmin) return;
    vec3 p[3];
    for (int i = 0; i < 3; ++i) {
        vec3 c = v_cam[i];
        float r = length(c);
        float lon = atan(c.x, -c.z) / PI;                       // [-1, 1]
        float lat = asin(clamp(c.y / max(r, 1e-6), -1.0, 1.0)) / (0.5 * PI);
        p[i] = vec3(lon, -lat, r);
    }
    for (int i = 1; i < 3; ++i) {  // unwrap longitudes next to the first vertex
        if (p[i].x - p[0].x > 1.0) p[i].x -= 2.0;
        else if (p[i].x - p[0].x < -1.0) p[i].x += 2.0;
    }
    float lo = min(min(p[0].x, p[1].x), p[2].x);
    float hi = max(max(p[0].x, p[1].x), p[2].x);
    if (hi - lo > 0.5) return;  // wraps around a pole: longitude is meaningless there
    int copies = (lo < -1.0 || hi > 1.0) ? 2 : 1;
    float shift = (lo < -1.0) ? 2.0 : -2.0;
    for (int k = 0; k < copies; ++k) {
        float s = (k == 0) ? 0.0 : shift;
        for (int i = 0; i < 3; ++i) {
            gl_Position = vec4(p[i].x + s, p[i].y, 2.0 * clamp(p[i].z / u_far, 0.0, 1.0) - 1.0, 1.0);
            g_uv = v_uv[i];
            g_dist = p[i].z;
            EmitVertex();
        }
        EndPrimitive();
    }
}
