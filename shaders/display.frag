#version 330 core
// The viewer's display: an equirectangular texture (row 0 = top) shown whole (ERP mode) or
// through a pinhole camera looking down the panorama's -z (perspective mode), as colour or as
// colour-mapped distance. PERSPECTIVE (0: whole panorama, 1: pinhole view) and DEPTH (1: the
// texture holds distances in its red channel, metres) are defined at compile time: a CPU
// rasteriser would otherwise pay for both sides of each branch on every pixel. FILL (1: u_pano
// is the GL preview's blend, rgb premultiplied by coverage, and u_coarse its filled next
// coarser level) does the preview's last push-pull step here. ROTATE (1: u_pano is in another
// camera's frame, a source view) turns each viewing direction by u_rot first, so the source
// view follows the camera's heading. SHARP (1: the GL preview's sharp colours, computed here
// from its layers, preview_sharp.glsl; u_pano unused) saves the preview a full-resolution pass.
// The image fills the viewport at u_origin (window pixels, a letterbox keeps the whole
// panorama 2:1).
uniform sampler2D u_pano;
uniform sampler2D u_coarse;
uniform float u_fov;           // vertical field of view (radians)
uniform vec2 u_size;           // viewport size in pixels
uniform vec2 u_origin;         // viewport's bottom-left corner in window pixels
uniform mat3 u_rot;            // ROTATE: viewing direction -> the texture's camera frame
uniform float u_max_depth;
out vec4 out_color;
#if SHARP
#include "preview_sharp.glsl"
#endif

const float PI = 3.14159265358979;

vec3 turbo(float x) {  // a compact approximation of the Turbo colour map
    x = clamp(x, 0.0, 1.0);
    vec4 v4 = vec4(1.0, x, x * x, x * x * x);
    vec2 v2 = v4.zw * v4.z;
    return vec3(
        dot(v4, vec4(0.13572138, 4.61539260, -42.66032258, 132.13108234)) + dot(v2, vec2(-152.94239396, 59.28637943)),
        dot(v4, vec4(0.09140261, 2.19418839, 4.84296658, -14.18503333)) + dot(v2, vec2(4.27729857, 2.82956604)),
        dot(v4, vec4(0.10667330, 12.64194608, -60.58204836, 110.36276771)) + dot(v2, vec2(-89.90310912, 27.34824973)));
}

void main() {
    vec2 p = (gl_FragCoord.xy - u_origin) / u_size;  // (0, 0) bottom left
    vec2 uv;
#if PERSPECTIVE || ROTATE
#if PERSPECTIVE
    float f = 0.5 / tan(0.5 * u_fov);
    float aspect = u_size.x / u_size.y;
    vec3 d = normalize(vec3((p.x - 0.5) * aspect, p.y - 0.5, -f));
#else
    float lon0 = (p.x - 0.5) * 2.0 * PI;
    float lat0 = (p.y - 0.5) * PI;
    vec3 d = vec3(cos(lat0) * sin(lon0), sin(lat0), -cos(lat0) * cos(lon0));
#endif
#if ROTATE
    d = u_rot * d;
#endif
    float lon = atan(d.x, -d.z);
    float lat = asin(clamp(d.y, -1.0, 1.0));
    uv = vec2(lon / (2.0 * PI) + 0.5, 0.5 - lat / PI);
#else
    uv = vec2(p.x, 1.0 - p.y);
#endif
#if SHARP
    vec4 c = vec4(sharp_preview(uv), 1.0);
#elif FILL
    vec4 c = textureLod(u_pano, uv, 0.0);
    c = vec4(c.rgb + (1.0 - c.a) * texture(u_coarse, uv).rgb, 1.0);
#else
    vec4 c = texture(u_pano, uv);
#endif
#if DEPTH
    c = vec4(c.r > 0.0 ? turbo(c.r / u_max_depth) : vec3(0.0), 1.0);
#endif
    out_color = vec4(c.rgb, 1.0);
}
