#version 330 core
// GEO = 0: rgb, and the distance from the target in alpha on a log scale (see
// preview_mesh.vert): what the blend compares when it needs no exact distance. The exact
// distance is in the depth buffer.
// GEO = 1 (the sharp preview's layers, 32-bit floats): the unit direction in which the source
// saw this point, and the log distance. preview_sharp.frag samples them bilinearly at a finer
// resolution and reads the source in that direction; a direction, unlike the source's ERP
// coordinates, interpolates across the source's seam and around its poles.
uniform sampler2DArray u_images;  // the source panoramas, repeating in u
uniform float u_source;           // this mesh's source in u_images
in vec2 v_uv;
in vec3 v_dir;
in float v_log_dist;
layout(location = 0) out vec4 out_color;

void main() {
    float d = max(v_log_dist, 1.0 / 255.0);
#if GEO
    out_color = vec4(normalize(v_dir), d);
#else
    out_color = vec4(texture(u_images, vec3(v_uv, u_source)).rgb, d);
#endif
}
