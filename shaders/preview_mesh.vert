#version 330 core
// A source view's depth mesh projected straight into the target's equirectangular image.
// Row 0 of the framebuffer is the top row (latitude +90 deg), like the other ERP passes, so
// read-back needs no flip. Triangles that cross the target's seam are drawn separately (the
// CPU picks them per frame) with u_unwrap = 1, twice, as two instances of one draw: once as
// they are (instance 0) and once a full turn to the left (instance 1), so each side of the
// image gets its part.
in vec3 in_pos;       // world position (metres)
in vec2 in_uv;        // source texture coordinate; u > 1 on the column that closes the seam
in vec3 in_dir;       // the unit direction in which the source sees this point (its own frame)
uniform mat4 u_w2c;   // target world -> camera
uniform float u_far;  // metres mapped to the far end of the depth buffer (depth = r / u_far)
uniform int u_unwrap;
out vec2 v_uv;
out vec3 v_dir;
// Log distance, 0 at LOG_NEAR metres (defined at compile time), 1 at u_far; per vertex: cheaper.
out float v_log_dist;

#include "erp_uv.glsl"

void main() {
    vec3 c = (u_w2c * vec4(in_pos, 1.0)).xyz;
    float r = length(c);
    // Longitude in [-1, 1], latitude in [-1, 1], by the minimax arctangent of erp_uv.glsl:
    // cheaper than the built-in atan and asin on a CPU rasteriser, whose vertex stage runs
    // on the drawing thread (llvmpipe: 6.5 instead of 7.3 ms for three 10k-triangle meshes).
    float lon = erp_atan2(c.x, -c.z) * 0.31830989;
    float lat = erp_atan2(c.y, length(c.xz)) * 0.63661977;
    if (u_unwrap == 1 && lon < 0.0) lon += 2.0;
    v_uv = in_uv;
    v_dir = in_dir;
    v_log_dist = log(max(r, LOG_NEAR) / LOG_NEAR) / log(u_far / LOG_NEAR);
    float shift = -2.0 * float(gl_InstanceID);  // 0, or a full turn to the left
    gl_Position = vec4(lon + shift, -lat, 2.0 * clamp(r / u_far, 0.0, 1.0) - 1.0, 1.0);
}
