#version 450 core
// bcf_render.vert: the reference renderer's vertex shader (bcfpipe render, docs/render.md).
// Positions and normals arrive in world space; uViewProj is world -> clip.

uniform mat4 uViewProj;

layout(location = 0) in vec3 inPosition;
layout(location = 1) in vec3 inNormal;
layout(location = 2) in vec2 inSt;

layout(location = 0) out vec3 vPosition;
layout(location = 1) out vec3 vNormal;
layout(location = 2) out vec2 vSt;

void main() {
    vPosition = inPosition;
    vNormal = inNormal;
    vSt = inSt;
    gl_Position = uViewProj * vec4(inPosition, 1.0);
}
