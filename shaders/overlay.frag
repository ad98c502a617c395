#version 330 core
// The text overlay (an RGBA image, row 0 = top) drawn over the top-left corner of the window.
uniform sampler2D u_text;
uniform vec2 u_size;       // window size in pixels
uniform vec2 u_text_size;  // overlay size in pixels
out vec4 out_color;

void main() {
    vec2 px = vec2(gl_FragCoord.x, u_size.y - gl_FragCoord.y);  // from the top left
    if (px.x >= u_text_size.x || px.y >= u_text_size.y) discard;
    out_color = texture(u_text, px / u_text_size);
}
