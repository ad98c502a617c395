#version 330 core
// One "push" step of push-pull hole filling. The blended preview (rgb premultiplied by
// coverage, coverage in alpha) is mipmapped ("pull"); from the coarsest level down, each
// level's holes take the filled next coarser level, sampled bilinearly:
// filled = level + (1 - coverage) * filled(coarser). The coarsest level is normalised by its
// coverage instead; the last step (level 0) writes the preview.
uniform sampler2D u_level;    // the blended preview, mipmapped
uniform sampler2D u_coarser;  // the filled next coarser level
uniform int u_lod;            // which mip level of u_level this pass fills
uniform int u_coarsest;       // 1: no coarser level
uniform vec2 u_size;          // this level's size in pixels
out vec4 out_color;

void main() {
    vec4 c = texelFetch(u_level, ivec2(gl_FragCoord.xy), u_lod);
    vec3 filled = u_coarsest == 1
        ? (c.a > 0.0 ? c.rgb / c.a : vec3(0.5))
        : c.rgb + (1.0 - c.a) * texture(u_coarser, gl_FragCoord.xy / u_size).rgb;
    out_color = vec4(filled, 1.0);
}
