#version 450
// Base colour = factor x texture x vertex colour (glTF). The texture's SRGB format decodes
// sRGB to linear when sampling; the SRGB colour target encodes on write.
// Lighting uses the geometric normal from screen-space derivatives (no normals needed), bent by the
// material's normal map when it has one. Every texture role is drawn: metallic-roughness (B metallic,
// G roughness: a metallic base colour and a GGX highlight), occlusion (R, on the ambient term) and
// emissive (added). The seed format carries no metallic, roughness, occlusion-strength or emissive
// factor, so the textures are drawn with factor 1 (the source reference likewise): the picture tests the
// textures. Without a metallic-roughness texture the lighting is the plain Lambert of before.
// PLAIN (compiled with -DPLAIN): for models without textures and with white vertex colours, the
// position is the only varying (lavapipe sets up every varying of every triangle).
layout(location = 0) in vec3 vPos;
#ifdef PLAIN
const vec4 vUV = vec4(0.0);
const vec4 vColor = vec4(1.0);
#else
layout(location = 1) in vec4 vUV;  // xy the layout's uv0 (the base colour's set), zw its uv1 (the other set)
layout(location = 2) in vec4 vColor;
#endif
layout(location = 0) out vec4 outColor;

struct Material {
    vec4 baseColor;   // linear RGBA factor
    vec4 params;      // x alphaCutoff, y alphaMode (0 OPAQUE, 1 MASK, 2 BLEND), z normal-map slot (0: none),
                      // w 1 (x, y, z stored) or 2 (x, y stored: z rebuilt)
    vec4 roles;       // slots: x metallic-roughness, y occlusion, z emissive (0: none)
    vec4 uvSets;      // the UV set each role samples (0 uv0, 1 uv1): x normal, y metallic-roughness,
                      // z occlusion, w emissive
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
    Material m = materials[pc.sel.x];
    vec2 uvN = m.uvSets.x > 0.5 ? vUV.zw : vUV.xy;  // the normal map's UV set
    vec3 dp1 = dFdx(vPos), dp2 = dFdy(vPos);  // derivatives first: before any discard
    vec2 duv1 = dFdx(uvN), duv2 = dFdy(uvN);
    vec3 n = normalize(cross(dp1, dp2));
    vec3 toEye = normalize(pc.eye.xyz - vPos);
    if (dot(n, toEye) < 0.0) n = -n;
    int nslot = int(m.params.z + 0.5);
    if (nslot > 0) {
        // Normal map in a per-pixel tangent frame from the position and UV derivatives (the
        // cotangent frame, Schueler 2013): the same frame for the build and its source, from the
        // geometry and UVs alone, so the picture changes with the normal map, not the frame.
        // glTF's green is +Y, towards decreasing V: the bitangent is -dP/dV.
        vec3 dp2perp = cross(dp2, n), dp1perp = cross(n, dp1);
        vec3 T = dp2perp * duv1.x + dp1perp * duv2.x;
        vec3 B = dp2perp * duv1.y + dp1perp * duv2.y;
        float scale = inversesqrt(max(max(dot(T, T), dot(B, B)), 1e-30));
        vec3 tn = texture(textures[nslot], uvN).xyz * 2.0 - 1.0;
        if (m.params.w > 1.5) tn.z = sqrt(max(0.0, 1.0 - dot(tn.xy, tn.xy)));  // BC5 / EAC RG11: x, y only
        vec3 mapped = T * scale * tn.x - B * scale * tn.y + n * tn.z;
        if (dot(mapped, mapped) > 1e-12) n = normalize(mapped);
    }
    vec4 base = m.baseColor * texture(textures[pc.sel.y], vUV.xy) * vColor;
    int mode = int(m.params.y + 0.5);
    if (mode == 1 && base.a < m.params.x) discard;
    if (mode != 2) base.a = 1.0;
    vec3 L = normalize(pc.lightDir.xyz);
    float nl = max(dot(n, L), 0.0);
    int mrslot = int(m.roles.x + 0.5), aoslot = int(m.roles.y + 0.5), emslot = int(m.roles.z + 0.5);
    float ao = aoslot > 0 ? texture(textures[aoslot], m.uvSets.z > 0.5 ? vUV.zw : vUV.xy).r : 1.0;
    vec3 rgb;
    if (mrslot > 0) {
        vec4 mr = texture(textures[mrslot], m.uvSets.y > 0.5 ? vUV.zw : vUV.xy);
        float metal = mr.b;
        float a = max(mr.g * mr.g, 0.02);  // GGX alpha = roughness^2, floored: no sub-pixel highlight
        vec3 f0 = mix(vec3(0.04), base.rgb, metal);
        vec3 h = normalize(L + toEye);
        float nh = max(dot(n, h), 0.0), nv = max(dot(n, toEye), 1e-3);
        float d = a * a / (3.14159265 * pow(nh * nh * (a * a - 1.0) + 1.0, 2.0));
        vec3 f = f0 + (1.0 - f0) * pow(1.0 - max(dot(h, toEye), 0.0), 5.0);
        float k = a / 2.0;                  // Smith-Schlick visibility
        float vis = 1.0 / ((nl * (1.0 - k) + k) * (nv * (1.0 - k) + k) * 4.0);
        vec3 spec = min(d * vis * f, vec3(8.0));
        vec3 diffuse = base.rgb * (1.0 - metal);
        rgb = (diffuse + f0) * 0.3 * ao + (diffuse + spec) * 0.7 * nl;
    } else {
        rgb = base.rgb * (0.3 * ao + 0.7 * nl);
    }
    if (emslot > 0) rgb += texture(textures[emslot], m.uvSets.w > 0.5 ? vUV.zw : vUV.xy).rgb;
    outColor = vec4(rgb, base.a);
    if (pc.sel.z == 3) {            // shaded + facing in one pass (OPAQUE materials, no culling): alpha 1
        outColor.a = (gl_FrontFacing || pc.sel.w == 1) ? 1.0 : 0.5;  // where the nearest surface faces the
    }                               // eye (or is double-sided), 0.5 where a back face is nearest
}
