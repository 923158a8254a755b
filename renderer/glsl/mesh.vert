#version 450
// assetpipe validation renderer: positions are model space, the model matrix is identity.
layout(location = 0) in vec3 inPos;
layout(location = 1) in vec2 inUV;
layout(location = 2) in vec4 inColor;
layout(location = 3) in vec2 inUV1;  // the layout's uv1 (the second UV set; zeros without one)

layout(push_constant) uniform PushConstants {
    mat4 viewProj;   // Vulkan clip space (y down, depth 0..1), column-major
    vec4 eye;        // camera position (xyz)
    vec4 lightDir;   // direction towards the light (xyz), model space
    ivec4 sel;       // x material index, y texture slot, z mode (0 shaded, 1 silhouette, 2 facing, 3 shaded+facing), w double-sided
} pc;

layout(location = 0) out vec3 vPos;
#ifndef PLAIN  // PLAIN: the position is the only varying (mesh.frag says when)
layout(location = 1) out vec4 vUV;  // xy uv0, zw uv1
layout(location = 2) out vec4 vColor;
#endif

void main() {
    vPos = inPos;
#ifndef PLAIN
    vUV = vec4(inUV, inUV1);
    vColor = inColor;
#endif
    gl_Position = pc.viewProj * vec4(inPos, 1.0);
}
