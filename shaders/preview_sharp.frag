#version 330 core
// The sharp preview (preview_sharp.glsl) as a pass of its own: u_size rows and columns of ERP,
// row 0 at the top like the other ERP passes.
#include "preview_sharp.glsl"
uniform vec2 u_size;  // this output's size in pixels
out vec4 out_color;

void main() {
    out_color = vec4(sharp_preview(gl_FragCoord.xy / u_size), 1.0);
}
