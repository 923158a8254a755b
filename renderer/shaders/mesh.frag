#version 450
// Base colour = factor x texture x vertex colour (glTF). The texture's SRGB format decodes
// sRGB to linear when sampling; the SRGB colour target encodes on write.
// Lighting uses the geometric normal from screen-space derivatives: no normals needed.
layout(location = 0) in vec3 vPos;
layout(location = 1) in vec2 vUV;
layout(location = 2) in vec4 vColor;
layout(location = 0) out vec4 outColor;

struct Material {
    vec4 baseColor;   // linear RGBA factor
    vec4 params;      // x alphaCutoff, y alphaMode (0 OPAQUE, 1 MASK, 2 BLEND), z, w unused
};
layout(std430, set = 0, binding = 0) readonly buffer Materials { Material materials[]; };
// Fixed-size array (lavapipe has no descriptor indexing), indexed by a push constant:
// dynamically uniform. Unused slots hold a 1x1 white texture.
layout(set = 0, binding = 1) uniform sampler2D textures[16];

layout(push_constant) uniform PushConstants {
    mat4 viewProj;
    vec4 eye;
    vec4 lightDir;
    ivec4 sel;       // x material, y texture slot, z mode (0 shaded, 1 silhouette, 2 facing, 3 shaded+facing), w double-sided
} pc;

void main() {
    if (pc.sel.z == 1) {            // silhouette: coverage only
        outColor = vec4(1.0);
        return;
    }
    if (pc.sel.z == 2) {            // facing: red 1 where the nearest surface faces the eye (or is
        outColor = vec4((gl_FrontFacing || pc.sel.w == 1) ? 1.0 : 0.5, 0.0, 0.0, 1.0);  // double-sided), 0.5 where
        return;                     // a back face is nearest; alpha 1 wherever anything covers
    }
    vec3 n = normalize(cross(dFdx(vPos), dFdy(vPos)));
    vec3 toEye = normalize(pc.eye.xyz - vPos);
    if (dot(n, toEye) < 0.0) n = -n;
    Material m = materials[pc.sel.x];
    vec4 base = m.baseColor * texture(textures[pc.sel.y], vUV) * vColor;
    int mode = int(m.params.y + 0.5);
    if (mode == 1 && base.a < m.params.x) discard;
    if (mode != 2) base.a = 1.0;
    float diffuse = max(dot(n, normalize(pc.lightDir.xyz)), 0.0);
    outColor = vec4(base.rgb * (0.3 + 0.7 * diffuse), base.a);
    if (pc.sel.z == 3) {            // shaded + facing in one pass (OPAQUE materials, no culling): alpha 1
        outColor.a = (gl_FrontFacing || pc.sel.w == 1) ? 1.0 : 0.5;  // where the nearest surface faces the
    }                               // eye (or is double-sided), 0.5 where a back face is nearest
}
