// Morph-target blending of a talking head. The deltas of the 20 target slots (15 visemes, then
// the eyes: blink, look up, down, left, right) are uploaded once as one storage buffer (6 floats
// per vertex per slot: position xyz, normal xyz, one block of vertices per slot); the weights are
// a small storage buffer rewritten every frame, and the weighted sum is done here per vertex.
// Head motion (a rotation about the neck) is part of the model matrix.

struct View {
    view_proj: mat4x4<f32>,
    model: mat4x4<f32>,
    eye: vec4<f32>,
    light_dir: vec4<f32>,
    // x: vertices with morph deltas (they come first; stride between two visemes' blocks)
    // y: all vertices of the head
    // z: the first moving vertex that the eye shapes move too (the visemes alone move those
    //    before it), w: the first that only the eye shapes move
    counts: vec4<u32>,
    // The head variant (src/render/variant.rs), all changes zero for the head as modelled so that
    // `c + change` leaves it exact: the skin's colour factor minus one (a: the bundled skin's
    // luminance), what the bundled hair colour gains beyond that (a: its luminance), the lips'
    // factor minus one; the face shape's scale minus one (xyz) and the morph motion's (w); the
    // normals' scale; the pivot it scales about.
    skin: vec4<f32>,
    hair: vec4<f32>,
    lips: vec4<f32>,
    shape: vec4<f32>,
    normal_scale: vec4<f32>,
    pivot: vec4<f32>,
}

// Slots blended: 15 visemes + 5 expressions (TARGET_COUNT in src/render/head.rs).
const TARGET_COUNT: u32 = 20u;

// The slots with weight this frame, compacted: `used.x` of them, `slot[k]` weighted `w[k]`; the
// first `used.y` are visemes, the rest eye shapes.
struct Weights {
    used: vec4<u32>,
    slot: array<vec4<u32>, 5>,
    w: array<vec4<f32>, 5>,
}

struct Material {
    base_color: vec4<f32>,
    // x: 1 where the variant recolours this material (the skin), else 0.
    recolour: vec4<f32>,
}

// Whether the material has a base colour texture. A pipeline constant rather than a uniform:
// untextured materials skip the sample (a good part of a fragment's cost on a software adapter)
// and lavapipe does not recompile the shader at every draw, as it does for uniform branches.
override TEXTURED: bool = true;

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<storage, read> weights: Weights;
@group(0) @binding(2) var<storage, read> deltas: array<f32>;

@group(1) @binding(0) var<uniform> material: Material;
@group(1) @binding(1) var base_tex: texture_2d<f32>;
@group(1) @binding(2) var base_sampler: sampler;

struct VertexIn {
    @location(0) position: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) color: vec4<f32>,
}

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) normal: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(3) color: vec4<f32>,
}

struct Blended {
    position: vec3<f32>,
    normal: vec3<f32>,
}

fn blend(vid: u32, position: vec3<f32>, normal: vec3<f32>) -> Blended {
    var p = position;
    var n = normal;
    let count = view.counts.x;
    // Vertices past `count` belong to meshes without morph targets and have no deltas. A select,
    // not a branch: lavapipe specialises shaders on uniforms that steer branches and loops, and
    // recompiles at every draw that binds them.
    let used = select(min(weights.used.x, TARGET_COUNT), 0u, vid >= count);
    // A vertex only the visemes move skips the eye shapes' slots, and the other way round.
    let visemes = min(weights.used.y, used);
    let first = select(0u, visemes, vid >= view.counts.w);
    let last = select(used, visemes, vid < view.counts.z);
    for (var k = first; k < last; k = k + 1u) {
        let t = weights.slot[k / 4u][k % 4u];
        let w = weights.w[k / 4u][k % 4u];
        let b = (t * count + vid) * 6u;
        p = p + w * vec3<f32>(deltas[b], deltas[b + 1u], deltas[b + 2u]);
        n = n + w * vec3<f32>(deltas[b + 3u], deltas[b + 4u], deltas[b + 5u]);
    }
    return Blended(p, n);
}

// The variant's face shape: the head scaled about its pivot, its morph motion scaled uniformly
// (by the sideways scale, so a mouth opens as far in eye widths as its calibration says). Written
// as offsets times (scale - 1), so the unchanged head's positions come out exact.
fn shaped(position: vec3<f32>, b: Blended) -> Blended {
    let p = b.position + (position - view.pivot.xyz) * view.shape.xyz
        + (b.position - position) * view.shape.w;
    return Blended(p, b.normal * view.normal_scale.xyz);
}

// The variant's colours on the skin material's albedo. Skin, cheeks, hair and brows share one
// hue (green about half of red) and differ in brightness: such a colour is read as skin and hair
// mixed by its luminance, plus a little else (the cheeks' red) that follows the skin.
// Its skin part takes the skin's factor and its hair part the new hair colour; a redder colour
// bright enough is lips (the inside of the mouth, darker, keeps its colour).
fn recolour(albedo: vec3<f32>) -> vec3<f32> {
    let l = dot(albedo, vec3<f32>(0.2126, 0.7152, 0.0722));
    let hue = smoothstep(0.30, 0.40, albedo.g / max(albedo.r, 1e-4));
    let hair = clamp((view.skin.a - l) / (view.skin.a - view.hair.a), 0.0, 1.0);
    let lips = (1.0 - hue) * smoothstep(0.06, 0.10, l);
    let change = hue * (albedo * view.skin.rgb + hair * view.hair.rgb) + lips * albedo * view.lips.rgb;
    return max(albedo + change * material.recolour.x, vec3<f32>(0.0));
}

// A vertex colour recoloured as its albedo would be (the fragment stage multiplies by the base
// colour factor and any texture after): per vertex, not per pixel, a fraction of the work on a
// software adapter. A texture's own colours are left as they are.
fn recolour_vertex(color: vec4<f32>) -> vec4<f32> {
    let base = material.base_color.rgb;
    let albedo = base * color.rgb;
    let change = (recolour(albedo) - albedo) / max(base, vec3<f32>(1e-4));
    return vec4<f32>(color.rgb + change, color.a);
}

@vertex
fn vs_main(in: VertexIn, @builtin(vertex_index) vid: u32) -> VertexOut {
    let b = shaped(in.position, blend(vid, in.position, in.normal));
    let world = view.model * vec4<f32>(b.position, 1.0);
    var out: VertexOut;
    out.clip = view.view_proj * world;
    out.world = world.xyz;
    // The model matrix (placement times head motion) is a rotation + uniform scale + translation,
    // so it transforms normals too (the face shape's scale is applied to them in `shaped`).
    out.normal = (view.model * vec4<f32>(b.normal, 0.0)).xyz;
    out.uv = in.uv;
    out.color = recolour_vertex(in.color);
    return out;
}

// Light at a surface point of normal `n` (unit, facing the viewer's side): rgb multiplies the
// albedo, a is added (specular and rim).
fn lighting(n: vec3<f32>, world: vec3<f32>) -> vec4<f32> {
    let v = normalize(view.eye.xyz - world);
    // Key light from above on one side; a weaker, cooler fill from the other side and lower, so
    // the lips' curl and the teeth keep their shape where the key does not reach.
    let key_dir = normalize(-view.light_dir.xyz);
    let fill_dir = normalize(vec3<f32>(-key_dir.x, -0.15, key_dir.z));
    let key = vec3<f32>(1.0, 0.95, 0.88) * max(dot(n, key_dir), 0.0);
    let fill = vec3<f32>(0.30, 0.33, 0.38) * max(dot(n, fill_dir), 0.0);
    let sky = 0.5 + 0.5 * n.y;
    let ambient = mix(vec3<f32>(0.07, 0.06, 0.06), vec3<f32>(0.15, 0.16, 0.18), sky);
    let key_half = normalize(key_dir + v);
    let fill_half = normalize(fill_dir + v);
    // Specular powers by repeated squaring: pow() is costly where shaders run on the CPU.
    let k = max(dot(n, key_half), 0.0);
    let k3 = k * k * k;
    let k12 = (k3 * k3) * (k3 * k3);
    let f = max(dot(n, fill_half), 0.0);
    let f4 = (f * f) * (f * f);
    let f16 = (f4 * f4) * (f4 * f4);
    let spec = 0.16 * (k12 * k12) * (k12 * k12) + 0.05 * f16 * f16;
    let edge = 1.0 - max(dot(n, v), 0.0);
    let rim = 0.08 * edge * edge * edge;
    return vec4<f32>(ambient + key + fill, spec + rim);
}

@fragment
fn fs_main(in: VertexOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    var texel = vec4<f32>(1.0);
    if (TEXTURED) {
        texel = textureSample(base_tex, base_sampler, in.uv);
    }
    let albedo = material.base_color * in.color * texel;
    var n = normalize(in.normal);
    if (!front) {
        n = -n;
    }
    let light = lighting(n, in.world);
    let lit = albedo.rgb * light.rgb + vec3<f32>(light.a);
    return vec4<f32>(lit, 1.0);
}

// Lit per vertex, for small heads on a software adapter, whose triangles are a few pixels each
// (`Shading` in src/render/renderer): a vertex's lighting is shared by the pixels around it, and
// the light and the untextured albedo are multiplied at the vertices, so that a pixel
// interpolates one colour (and the texture coordinate, if it samples) rather than the position,
// normal, colour and light (a tenth less time for eight small heads on lavapipe).
struct LitOut {
    @builtin(position) clip: vec4<f32>,
    // rgb: the albedo without its texture times the light; a: the specular and rim light added.
    @location(0) tint: vec4<f32>,
    @location(1) uv: vec2<f32>,
}

@vertex
fn vs_vertex_lit(in: VertexIn, @builtin(vertex_index) vid: u32) -> LitOut {
    let b = shaped(in.position, blend(vid, in.position, in.normal));
    let world = view.model * vec4<f32>(b.position, 1.0);
    let light = lighting(normalize((view.model * vec4<f32>(b.normal, 0.0)).xyz), world.xyz);
    var out: LitOut;
    out.clip = view.view_proj * world;
    out.tint = vec4<f32>(recolour((material.base_color * in.color).rgb) * light.rgb, light.a);
    out.uv = in.uv;
    return out;
}

@fragment
fn fs_vertex_lit(in: LitOut) -> @location(0) vec4<f32> {
    var texel = vec3<f32>(1.0);
    if (TEXTURED) {
        texel = textureSample(base_tex, base_sampler, in.uv).rgb;
    }
    return vec4<f32>(in.tint.rgb * texel + vec3<f32>(in.tint.a), 1.0);
}

// Debug/test entry: the same blend as the vertex stage, written out for readback.
@group(2) @binding(0) var<storage, read> blend_in: array<f32>;
@group(2) @binding(1) var<storage, read_write> blend_out: array<f32>;

@compute @workgroup_size(64)
fn cs_blend(@builtin(global_invocation_id) gid: vec3<u32>) {
    let vid = gid.x;
    if (vid >= view.counts.y) {
        return;
    }
    // Vertex layout: position(3) normal(3) uv(2) color(4) = 12 floats.
    let s = vid * 12u;
    let p = vec3<f32>(blend_in[s], blend_in[s + 1u], blend_in[s + 2u]);
    let n = vec3<f32>(blend_in[s + 3u], blend_in[s + 4u], blend_in[s + 5u]);
    let b = blend(vid, p, n);
    let o = vid * 6u;
    blend_out[o] = b.position.x;
    blend_out[o + 1u] = b.position.y;
    blend_out[o + 2u] = b.position.z;
    blend_out[o + 3u] = b.normal.x;
    blend_out[o + 4u] = b.normal.y;
    blend_out[o + 5u] = b.normal.z;
}
