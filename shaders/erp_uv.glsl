// A direction in a camera's frame -> that camera's ERP texture coordinates (u in [0, 1] from
// longitude -180 deg, v = 0 at the top), as the GL preview's layers need them per pixel and
// source (preview_blend.frag, preview_sharp.glsl). The arctangent is a minimax polynomial on
// [0, 1] with the octant's symmetries, good to about 1e-5 rad: cheaper than the built-in atan
// and asin on a CPU rasteriser, and far below a pixel (6e-3 rad at 1024 columns).
#ifndef ERP_UV_GLSL
#define ERP_UV_GLSL
float erp_atan2(float y, float x) {
    float ax = abs(x), ay = abs(y);
    float a = min(ax, ay) / max(max(ax, ay), 1e-20);
    float s = a * a;
    float r = ((-0.0464964749 * s + 0.15931422) * s - 0.327622764) * s * a + a;
    r = ay > ax ? 1.57079637 - r : r;
    r = x < 0.0 ? 3.14159274 - r : r;
    return y < 0.0 ? -r : r;
}

vec2 erp_uv(vec3 d) {
    return vec2(erp_atan2(d.x, -d.z) * 0.15915494 + 0.5, 0.5 - erp_atan2(d.y, length(d.xz)) * 0.31830989);
}
#endif
