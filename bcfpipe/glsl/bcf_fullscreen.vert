#version 450 core
// Full-screen pass for bcf_fullscreen.frag: one triangle covering the viewport, no vertex buffer
// (draw 3 vertices with an empty vertex array). Needs no library.
//
// uniform vec4 uUvTransform   uv = screen position in [0, 1]^2 * xy + zw   (host sets (1, 1, 0, 0)
//                             for one copy of the material; uniforms default to 0 in GL)

uniform vec4 uUvTransform;

layout(location = 0) out vec2 vUv;

void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));  // (0,0) (2,0) (0,2)
    vUv = p * uUvTransform.xy + uUvTransform.zw;
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
