#version 450
// mesh.frag's modes 1 (silhouette: white) and 2 (facing: red 1 where the nearest surface faces the
// eye or is double-sided, 0.5 where a back face is nearest), without inputs.
layout(location = 0) out vec4 outColor;

layout(push_constant) uniform PushConstants {
    mat4 viewProj;
    vec4 eye;
    vec4 lightDir;
    ivec4 sel;       // x material, y texture slot, z mode (1 silhouette, 2 facing), w double-sided
} pc;

void main() {
    if (pc.sel.z == 2) {
        outColor = vec4((gl_FrontFacing || pc.sel.w == 1) ? 1.0 : 0.5, 0.0, 0.0, 1.0);
    } else {
        outColor = vec4(1.0);
    }
}
