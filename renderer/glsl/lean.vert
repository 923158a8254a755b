#version 450
// Coverage, silhouette and facing renders: the position only (no varyings), so lavapipe's triangle
// set-up interpolates nothing (mesh.vert's three varyings cost set-up work on every triangle).
layout(location = 0) in vec3 inPos;

layout(push_constant) uniform PushConstants {
    mat4 viewProj;
    vec4 eye;
    vec4 lightDir;
    ivec4 sel;
} pc;

void main() {
    gl_Position = pc.viewProj * vec4(inPos, 1.0);
}
