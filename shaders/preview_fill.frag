#version 330 core
// Fills the holes of the blended preview (what no source saw: disocclusions, the poles) from
// ever coarser mipmap levels of the coverage-weighted colour (push-pull): a hole takes the
// average colour of the nearest covered surroundings.
uniform sampler2D u_blend;   // rgb * coverage, coverage in alpha; mipmapped
uniform vec2 u_size;
out vec4 out_color;

void main() {
    vec2 uv = gl_FragCoord.xy / u_size;
    vec4 c = texelFetch(u_blend, ivec2(gl_FragCoord.xy), 0);
    for (int level = 1; level < 10 && c.a < 0.999; ++level) {
        vec4 m = textureLod(u_blend, uv, float(level));
        if (m.a > 1e-3) c = vec4(mix(m.rgb / m.a, c.rgb, c.a), 1.0);
    }
    out_color = vec4(c.rgb, 1.0);
}
