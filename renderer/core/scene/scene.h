// The renderable scene: flat world-space triangle arrays, a material table and analytic
// sphere lights, built into one Embree 3 BVH. Emitters (emissive triangles and spheres)
// are indexed once so that next event estimation and MIS share one light sampler.
#pragma once

#include <embree3/rtcore.h>

#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "bsdf.h"
#include "bvh_light_sampler.h"
#include "light.h"
#include "light_kinds.h"
#include "light_links.h"
#include "light_sampler.h"
#include "math.h"
#include "grid_medium.h"
#include "medium.h"
#include "texture.h"

namespace tessera {

// The UsdPreviewSurface inputs an image texture can drive (UsdUVTexture outputs bound to
// them). occlusion is not among them: a path tracer computes occlusion itself.
enum TextureSlot : uint8_t {
    kSlotDiffuseColor,
    kSlotEmissiveColor,
    kSlotSpecularColor,
    kSlotMetallic,
    kSlotRoughness,
    kSlotClearcoat,
    kSlotClearcoatRoughness,
    kSlotOpacity,
    kSlotIor,
    kSlotNormal,
    kNumTextureSlots
};
constexpr std::array<int32_t, kNumTextureSlots> NoTextures() {
    std::array<int32_t, kNumTextureSlots> a{};
    for (auto& x : a) x = -1;
    return a;
}

struct Material {
    Color albedo;              // Lambertian reflectance, each channel in [0, 1]
    Color emission;            // emitted radiance (W m^-2 sr^-1, linear RGB)
    bool two_sided_emission = false;  // else emits only on the geometric normal's side
    // A UsdPreviewSurface; without it the surface is a pure Lambertian of `albedo`. Scene
    // turns a preview surface that equals a Lambertian exactly (specularColor 0, or ior 1,
    // opaque, no clearcoat, untextured) into one.
    std::optional<MaterialParams> preview;
    // Texture index per TextureSlot (-1: the constant above). Only preview materials use them.
    std::array<int32_t, kNumTextureSlots> textures = NoTextures();
    // A shaped area light (UsdLux ShapingAPI on a Rect or Disk light): its emission times
    // SceneDesc::emission_shapings[emission_shaping] about the emitting normal; -1: none.
    int32_t emission_shaping = -1;
    // The media on either side (media/medium.h; docs/media.md), and whether the surface is
    // only their boundary: no BSDF, rays pass it unchanged (pbrt-v4's material-less surfaces).
    MediumInterface media;
    bool interface_only = false;
    // Light linking (light_links.h): the link group of the surfaces using this row, and for
    // an area light's own row, its light link (-1: the default, lights everything).
    uint32_t link_group = 0;
    int32_t light_link = -1;
};

// A triangle mesh as flat arrays: the world's, or an instancing prototype's (in its own space).
struct MeshDesc {
    std::vector<float> positions;            // 3 floats per vertex
    std::vector<uint32_t> indices;           // 3 vertex indices per triangle
    std::vector<uint32_t> triangle_material; // one material index per triangle
    std::vector<float> shading_normals;      // optional: 9 floats per triangle (3 corner normals)
    std::vector<float> uvs;                  // optional: 6 floats per triangle (3 corner st)
    // Deformation (prototypes only): the vertices at time steps 1 .. T-1 after `positions`
    // (step 0), each step 3 floats per vertex in the same order; steps are evenly spaced
    // over the shutter and interpolated linearly between, as Embree does. Empty: rigid.
    std::vector<float> motion_positions;
};

// Input to Scene. Plain arrays, as the USD translation produces them.
struct SceneDesc {
    std::vector<float> positions;            // 3 floats per vertex, world space
    std::vector<uint32_t> indices;           // 3 vertex indices per triangle
    std::vector<uint32_t> triangle_material; // one material index per triangle
    std::vector<float> shading_normals;      // optional: 9 floats per triangle (3 corner normals)
    std::vector<float> uvs;                  // optional: 6 floats per triangle (3 corner st)
    // Image textures (Material::textures index `textures`).
    std::vector<Image> images;
    std::vector<TextureDesc> textures;
    // Instancing: prototypes are built once into their own BVH; instance i places
    // prototype instance_prototype[i] with instance_transforms[12 i ..], a row-major 3x4
    // matrix (world = M (p, 1)). Instances never copy triangles.
    std::vector<MeshDesc> prototypes;
    std::vector<uint32_t> instance_prototype;
    std::vector<float> instance_transforms;
    // Transform motion: instance motion_instances[k] moves through motion_time_steps[k]
    // matrices (>= 2), evenly spaced over the shutter (step j at shutter time j / (T - 1)),
    // taken in order from motion_transforms (12 floats each, as instance_transforms);
    // between steps the matrix is interpolated linearly, as Embree does. Its
    // instance_transforms entry is the first step's.
    std::vector<uint32_t> motion_instances;
    std::vector<uint32_t> motion_time_steps;
    std::vector<float> motion_transforms;
    // Moving lights: light light_motion_indices[k] of kind light_motion_kinds[k] (a sphere,
    // point or distant light, or the dome with index 0) moves rigidly through
    // light_motion_time_steps[k] (>= 2) world-space transforms taken in order from
    // light_motion_transforms (row-major 3x4, 12 floats each), evenly spaced over the
    // shutter and interpolated linearly: at step j the light is the one described here
    // moved by matrix j (its centre, position, shaping axis, direction or dome rotation;
    // a sphere keeps its radius). Moving spheres share the sphere geometry's time steps:
    // each is resampled at the largest step count among them.
    std::vector<LightKind> light_motion_kinds;
    std::vector<uint32_t> light_motion_indices;
    std::vector<uint32_t> light_motion_time_steps;
    std::vector<float> light_motion_transforms;
    // The lights of the kinds handed over in rows (light_kinds.h, kRowColumnsOf), by
    // LightKind number: each kind's rows back to back, kRowColumnsOf<Kind> floats a row.
    std::vector<std::vector<float>> light_rows;
    // Curves (UsdGeom BasisCurves of the world, static): Embree round linear curves, cones
    // between spheres. curve_points holds 4 floats per control point (x, y, z, radius);
    // segment s joins points curve_segments[s] and curve_segments[s] + 1, has the material
    // curve_material[s], and flags curve_flags[s] (RTC_CURVE_FLAG_NEIGHBOR_LEFT / RIGHT:
    // the segment before / after it belongs to the same curve).
    std::vector<float> curve_points;
    std::vector<uint32_t> curve_segments;
    std::vector<uint8_t> curve_flags;
    std::vector<uint32_t> curve_material;
    // How next event estimation chooses lights (Scene::SampleLight): automatic (the light
    // BVH from kMinLightBVHEmitters still area emitters on), always by power, or by the
    // BVH whenever there is a still area emitter.
    enum class LightSelection : uint8_t { kAuto, kPower, kBVH };
    LightSelection light_selection = LightSelection::kAuto;
    std::vector<Material> materials;
    std::vector<HomogeneousMedium> media;  // Material::media's indices
    // Light linking (light_links.h): the groups Material::link_group names, and the link
    // of each sphere, point and distant light and of the dome (-1 or missing: the default).
    // Area lights carry theirs in their material (Material::light_link).
    LightLinkTable light_links;
    std::vector<int32_t> sphere_light_link, point_light_link, distant_light_link;
    int32_t dome_light_link = -1;
    // Heterogeneous media (media/grid_medium.h): Material::media indices media.size() and on.
    std::vector<GridMedium> grid_media;
    std::vector<LightShaping> emission_shapings;  // Material::emission_shaping (axes used when about_axis)
    std::vector<SphereLight> sphere_lights;
    std::vector<PointLight> point_lights;
    std::vector<DistantLight> distant_lights;
    Color dome_radiance;  // constant environment radiance (the scale of a texture); black = no dome
    // Optional lat-long texture (OpenEXR convention, +Y pole in the dome's own space):
    // radiance = dome_radiance * texel. world_to_light is row-major (the dome's rotation,
    // poleAxis included).
    uint32_t dome_width = 0, dome_height = 0;
    std::vector<float> dome_rgb;  // dome_height rows of dome_width RGB texels
    float dome_world_to_light[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
};

inline constexpr uint32_t kNoInstance = 0xFFFFFFFFu;

// The row-major inverse transpose of row-major 3x4 m's 3x3 part (cofactors over the
// determinant): it transforms normals. Returns the determinant; n is untouched when it is
// zero or not finite.
inline double NormalMatrixOf(const float* m, float* n) {
    const double c00 = double(m[5]) * m[10] - double(m[6]) * m[9], c01 = double(m[6]) * m[8] - double(m[4]) * m[10],
                 c02 = double(m[4]) * m[9] - double(m[5]) * m[8];
    const double c10 = double(m[2]) * m[9] - double(m[1]) * m[10], c11 = double(m[0]) * m[10] - double(m[2]) * m[8],
                 c12 = double(m[1]) * m[8] - double(m[0]) * m[9];
    const double c20 = double(m[1]) * m[6] - double(m[2]) * m[5], c21 = double(m[2]) * m[4] - double(m[0]) * m[6],
                 c22 = double(m[0]) * m[5] - double(m[1]) * m[4];
    const double det = double(m[0]) * c00 + double(m[1]) * c01 + double(m[2]) * c02;
    if (!(std::abs(det) > 1e-30) || !std::isfinite(det)) return det;
    const double cof[9] = {c00, c01, c02, c10, c11, c12, c20, c21, c22};
    for (int j = 0; j < 9; ++j) n[j] = float(cof[j] / det);
    return det;
}

// The instant at which this thread's scene queries see moving geometry, as a fraction of
// the shutter interval in [0, 1] (Embree's ray time). RenderTile sets it once per camera
// sample (ShutterTimeScope), so every ray of the sample -- its camera path, shadow rays,
// and the light subpaths light, bdpt and vcm trace for it -- sees one consistent instant
// without each integrator threading it through every query. Scene passes set it per
// photon or light path (LightPathInstant); everywhere else (a radiosity solve) it stays
// 0.5: the scene frozen at mid-shutter. A static scene ignores it.
inline thread_local float tls_shutter_time = 0.5f;

// Embree's time model: time_steps (>= 2) steps evenly spaced over the shutter [0, 1],
// linear in between. The segment k holding this thread's shutter time, and the fraction f
// of the way through it.
inline void ShutterSegment(uint32_t time_steps, uint32_t* k, float* f) {
    const float t = std::clamp(tls_shutter_time, 0.f, 1.f) * float(time_steps - 1);
    *k = std::min(uint32_t(t), time_steps - 2);
    *f = t - float(*k);
}

// The row-major 3x4 matrix at this thread's shutter time of `time_steps` (>= 2) matrices
// (12 floats each, from `steps`), written to scratch.
inline const float* MatrixAtShutterTime(const float* steps, uint32_t time_steps, float* scratch) {
    uint32_t k;
    float f;
    ShutterSegment(time_steps, &k, &f);
    const float* a = steps + 12 * size_t(k);
    const float* b = a + 12;
    for (int j = 0; j < 12; ++j) scratch[j] = (1.f - f) * a[j] + f * b[j];
    return scratch;
}

// The camera that textures are filtered for. RenderTile sets it for its camera samples
// (TextureFootprintScope); every surface a sample's paths shade, first hit or after any
// bounce, filters its textures over the footprint this camera's pixel would have there
// (pbrt-v4's camera approximation): never wider for rough or curved surfaces on the way,
// so secondary hits are filtered at most as much as if seen directly. Without it (scene
// passes, a radiosity solve) lookups are point lookups on the finest level. It depends
// only on the camera and the hit point, not on spp, the tile or the thread: a farm job's
// images stay bit-identical to a local render's.
//
// The footprint is a quarter of the pixel's: the pixel's samples already average over the
// pixel, so the texture filter only has to remove what falls between them. A whole pixel
// blurs twice (relMSE 4x that of no filtering at 16 spp on a checker to the horizon);
// pbrt-v4 scales by 1 / sqrt(spp), but a fixed fraction keeps render passes composable
// (samples [a, b) and [b, c) make [a, c)). A quarter beat no filtering at 1, 4, 16 and 64 spp
// (docs/benchmarks/textures.md).
constexpr float kFootprintPixelFraction = 0.25f;

struct TextureFootprintCamera {
    Vec3 origin;
    Vec3 forward;
    bool orthographic = false;
    // kFootprintPixelFraction of a pixel's width: an angle at the image centre (perspective),
    // in scene units (orthographic).
    float pixel_angle = 0.f, pixel_width = 0.f;
};
inline thread_local const TextureFootprintCamera* tls_footprint_camera = nullptr;

class TextureFootprintScope {
public:
    explicit TextureFootprintScope(const TextureFootprintCamera* camera) : saved_(tls_footprint_camera) {
        tls_footprint_camera = camera;
    }
    ~TextureFootprintScope() { tls_footprint_camera = saved_; }
    TextureFootprintScope(const TextureFootprintScope&) = delete;
    TextureFootprintScope& operator=(const TextureFootprintScope&) = delete;

private:
    const TextureFootprintCamera* saved_;
};

// Row-major 3x4 m applied to a point and to a vector; row-major 3x3 n to a vector.
inline Vec3 TransformPoint(const float* m, Vec3 p) {
    return {m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3], m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
            m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]};
}
inline Vec3 TransformVector(const float* m, Vec3 v) {
    return {m[0] * v.x + m[1] * v.y + m[2] * v.z, m[4] * v.x + m[5] * v.y + m[6] * v.z,
            m[8] * v.x + m[9] * v.y + m[10] * v.z};
}
inline Vec3 TransformNormal(const float* n, Vec3 v) {
    return {n[0] * v.x + n[1] * v.y + n[2] * v.z, n[3] * v.x + n[4] * v.y + n[5] * v.z,
            n[6] * v.x + n[7] * v.y + n[8] * v.z};
}
// n^T v: with n = NormalMatrixOf(m), the inverse of m's 3x3 part applied to v.
inline Vec3 TransformByInverse(const float* n, Vec3 v) {
    return {n[0] * v.x + n[3] * v.y + n[6] * v.z, n[1] * v.x + n[4] * v.y + n[7] * v.z,
            n[2] * v.x + n[5] * v.y + n[8] * v.z};
}

class ShutterTimeScope {
public:
    explicit ShutterTimeScope(float time) : saved_(tls_shutter_time) { tls_shutter_time = time; }
    ~ShutterTimeScope() { tls_shutter_time = saved_; }
    ShutterTimeScope(const ShutterTimeScope&) = delete;
    ShutterTimeScope& operator=(const ShutterTimeScope&) = delete;

private:
    float saved_;
};

struct SurfaceHit {
    float t = 0.f;
    Vec3 p;
    float p_error = 0.f;  // |p - the true surface point| per axis is at most this (OffsetRayOrigin)
    Vec3 ng;  // unit geometric normal, as wound (not flipped toward the ray), world space
    // Unit shading normal (interpolated authored normals, else ng; then the normal map, if
    // any), on ng's side, world space.
    Vec3 ns;
    uint32_t geom_id = 0, prim_id = 0;  // geom_id: Scene::kTriangleGeometry for every triangle
    uint32_t mesh = 0;                  // 0: the world mesh; 1 + k: prototype k
    uint32_t instance = kNoInstance;    // the instance a prototype triangle was hit through
    float b1 = 0.f, b2 = 0.f;           // barycentrics of corners 1 and 2 (Embree's u, v)
    Vec2 st;                            // interpolated texture coordinates (0 without uvs)
};

// Shading normals bend the BSDF's frame away from the geometry. Two rules keep that
// physical (Veach 1997, 5.3): a scattering is allowed only if the shading frame and the
// geometry agree on whether it is a reflection or a transmission (no light leaks through
// surfaces), and light transported as importance (light subpaths) is multiplied by
// |wo.ns| |wi.ng| / (|wo.ng| |wi.ns|) so that the adjoint BSDF stays correct.
inline bool SidesAgree(Vec3 wo, Vec3 wi, Vec3 ng, Vec3 wo_local, Vec3 wi_local) {
    return (Dot(wo, ng) * Dot(wi, ng) > 0.f) == (wo_local.z * wi_local.z > 0.f);
}
inline float ImportanceShadingCorrection(Vec3 wo, Vec3 wi, Vec3 ns, Vec3 ng) {
    float denom = std::abs(Dot(wo, ng)) * std::abs(Dot(wi, ns));
    return denom > 0.f ? std::abs(Dot(wo, ns)) * std::abs(Dot(wi, ng)) / denom : 0.f;
}

class Scene {
public:
    static constexpr uint32_t kTriangleGeometry = 0;
    static constexpr uint32_t kSphereGeometry = 1;
    static constexpr uint32_t kCurveGeometry = 2;
    static constexpr int32_t kNoEmitter = -1;

    // Validates the description (indices in range, finite positions, material indices,
    // non-negative finite colours) and throws std::invalid_argument naming the problem.
    explicit Scene(const SceneDesc& desc);
    ~Scene();
    Scene(const Scene&) = delete;
    Scene& operator=(const Scene&) = delete;

    // Cutout surfaces (opacity below a positive opacityThreshold) are passed through.
    // Inline: most scenes have neither cutouts nor normal maps, and go straight to Embree.
    bool Intersect(const Ray& ray, SurfaceHit* hit, float t_min = 0.f,
                   float t_max = std::numeric_limits<float>::infinity()) const {
        if (!kFullFeatures || (!has_cutouts_ && !has_normal_maps_)) return IntersectClosest(ray, t_min, t_max, hit);
        if (!IntersectSurface(ray, hit, t_min, t_max)) return false;
        ApplyNormalMap(hit);
        return true;
    }
    bool Occluded(Vec3 origin, Vec3 dir, float t_far) const;
    // Closest hits of up to 8 rays at once (lanes with active[i] false are skipped): through
    // rtcIntersect8 for width 8, rtcIntersect4 for 4, rtcIntersect1 per ray for 1. found[i]
    // says whether lane i hit. For scenes Intersect sends straight to Embree (no cutouts,
    // no normal maps: packets_apply()); hits are those IntersectClosest builds.
    static constexpr int kMaxPacket = 8;
    void IntersectPacket(int width, const bool* active, const Ray* rays, const float* t_min, const float* t_max,
                         SurfaceHit* hits, bool* found) const;
    bool packets_apply() const { return !kFullFeatures || (!has_cutouts_ && !has_normal_maps_); }
    // Is the segment between two points free? Each end lies within its error bound of a
    // surface with geometric normal n (n = 0: not on a surface, as a point light or the
    // lens), and each is moved off its own surface toward the other before the ray is
    // traced (pbrt-v4's SpawnRayTo, applied at both ends), so the segment can hit neither
    // end's surface however far from the origin the two points lie. Moving only the origin
    // lets the ray reach the light's own surface wherever rounding put the light sample
    // behind it: 90 % of shadow rays 1e3 units from the origin were blocked that way.
    bool Unoccluded(Vec3 p0, float p0_error, Vec3 n0, Vec3 p1, float p1_error, Vec3 n1) const;
    // The same for a light sample seen from p: to its point, or toward infinity.
    bool Unoccluded(Vec3 p, float p_error, Vec3 ng, const LightSample& ls) const;

    const Material& MaterialAt(const SurfaceHit& hit) const;
    // The scattering function at a hit; a black DiffuseBSDF on light-only geometry.
    BSDF BSDFAt(const SurfaceHit& hit, TransportMode mode) const;
    // The st footprint of tls_footprint_camera's pixel at a triangle hit (what BSDFAt
    // filters its textures over); zero without that camera or without st.
    TextureFootprint FootprintAt(const SurfaceHit& hit) const;
    int32_t EmitterAt(const SurfaceHit& hit) const;
    // Radiance leaving emitter e at the hit toward wo.
    Color Emitted(int32_t emitter, const SurfaceHit& hit, Vec3 wo) const;

    // All lights (area emitters first, then the other kinds in LightKinds order), chosen by power.
    const LightSampler& light_sampler() const { return light_sampler_; }
    // Next event estimation's choice of a light for a shading point p with normal n (zero:
    // any orientation). With at least kMinLightBVHEmitters still area emitters, those are
    // chosen through a light BVH (bvh_light_sampler.h) that weighs their power by how much
    // of it can reach p; the other lights (and every light in smaller scenes) by power, as
    // light_sampler() chooses them. LightPmf is the probability SampleLight picks `light`
    // at (p, n): BSDF-sampled hits on an emitter weigh themselves with it under MIS.
    // `group`: the link group of the surface at p (LinkGroupAt); in a scene with light
    // links, only the lights that illuminate it are chosen, by the group's own tables.
    // kNoLinkGroup (and any group in a scene without links) chooses among all lights.
    static constexpr size_t kMinLightBVHEmitters = 16;
    static constexpr uint32_t kNoLinkGroup = 0xFFFFFFFFu;
    bool SampleLight(float u, Vec3 p, Vec3 n, uint32_t* light, float* pmf, uint32_t group = kNoLinkGroup) const {
        if (kFullFeatures && group != kNoLinkGroup && has_light_links_) return SampleLinkedLight(u, p, n, light, pmf, group);
        return SampleAnyLight(u, p, n, light, pmf);
    }
    float LightPmf(Vec3 p, Vec3 n, uint32_t light, uint32_t group = kNoLinkGroup) const {
        if (kFullFeatures && group != kNoLinkGroup && has_light_links_) return LinkedLightPmf(p, n, light, group);
        return AnyLightPmf(p, n, light);
    }
    bool uses_light_bvh() const { return !light_bvh_.empty(); }

    // Light linking and shadow linking (light_links.h). A scene without links pays one
    // predictable branch per query: has_light_links() is false, every light lights all.
    bool has_light_links() const { return kFullFeatures && has_light_links_; }
    // Lights whose light or shadow link leaves some surface of the scene out.
    size_t num_linked_lights() const { return num_linked_lights_; }
    // The link group of the surface at a hit (group 0 for a sphere light's own surface).
    uint32_t LinkGroupAt(const SurfaceHit& hit) const {
        const int64_t mi = MaterialIndexAt(hit);
        return mi < 0 ? 0u : materials_[size_t(mi)].link_group;
    }
    // Whether emitter `light` illuminates surfaces of link group `group`.
    bool Illuminates(uint32_t light, uint32_t group) const {
        return !has_light_links() || light_links_.Illuminates(emitter_link_[light], group);
    }
    // Whether some surface does not cast emitter `light`'s shadows. A BSDF-sampled ray stops
    // at the first surface, shadow-casting or not, so it cannot find such a light behind
    // one: path tracing estimates these lights by light sampling alone (MIS weight 1).
    bool ExcludesShadows(uint32_t light) const {
        return has_light_links() && light_links_.ExcludesShadows(emitter_link_[light]);
    }
    // Unoccluded(p, p_error, ng, ls) for a sample of emitter `light`: surfaces its shadow
    // link excludes let the shadow ray through.
    bool UnoccludedToLight(uint32_t light, Vec3 p, float p_error, Vec3 ng, const LightSample& ls) const {
        if (!ExcludesShadows(light)) return Unoccluded(p, p_error, ng, ls);
        return UnoccludedPastUnlinked(emitter_link_[light], p, p_error, ng, ls);
    }
    bool SampleEmitter(uint32_t emitter, Vec3 ref, Vec2 u, LightSample* out) const;
    // Solid-angle pdf at ref of SampleEmitter having produced the point of `hit`.
    float EmitterPdf(uint32_t emitter, Vec3 ref, const SurfaceHit& hit) const;

    // Samples a ray leaving light `emitter` (for light tracing and bidirectional methods).
    // Area lights: uniform point, cosine-weighted direction; points: uniform direction;
    // lights at infinity: a direction, then a point on the scene's bounding disk across it.
    bool SampleEmission(uint32_t emitter, Vec2 u_pos, Vec2 u_dir, float u_side, EmissionSample* out) const;

    // Emission sample `es` of a finite light, had it left toward w instead of es.wo: the
    // numerator Le(w) |cos| of its throughput (a point light's intensity I(w)) and
    // SampleEmission's direction density of w (photon emission aimed elsewhere weighs
    // itself by the mixture). False for lights at infinity.
    bool EmissionToward(uint32_t emitter, const EmissionSample& es, Vec3 w, Color* Le_cos, float* pdf_dir) const;

    // Densities of SampleEmission, for bidirectional MIS.
    // Direction: a finite light at a point with normal n (zero for points) emitting toward w.
    float EmissionPdfDirection(uint32_t emitter, Vec3 n, Vec3 w) const;
    // Position: 1/area for area lights, 1 for points, the bounding disk's for lights at infinity.
    float EmissionPdfPosition(uint32_t emitter) const;
    // Sum over lights at infinity of pmf * solid-angle density of their emitting toward -w
    // (w points from point p of the scene toward the light). Zero for delta-distant lights.
    float InfiniteLightDensity(Vec3 p, Vec3 w) const;
    bool IsInfiniteLight(uint32_t emitter) const;
    bool IsDeltaLight(uint32_t emitter) const;
    float scene_radius() const { return scene_radius_; }
    Vec3 scene_center() const { return scene_center_; }
    // Splats are stored in units of 2^splat_exponent() (see SplatFilm).
    int splat_exponent() const { return splat_exponent_; }

    // Lights at infinity seen along a ray from `origin` that escapes the scene in `dir`:
    // calls visit(light_index, radiance, solid-angle pdf of sampling that direction from
    // it). The origin matters to portals: only rays through one see the dome.
    template <typename Visit>
    void ForEachEnvironmentLight(Vec3 origin, Vec3 dir, Visit&& visit) const;
    // The name of a light kind in the scene that cannot start light subpaths
    // (kStartsLightPathsOf), or nullptr: integrators that trace them refuse such a scene.
    const char* kind_without_light_paths() const { return kind_without_light_paths_; }
    bool has_environment() const { return !environment_lights_.empty(); }
    // Every material is a plain Lambertian (no UsdPreviewSurface): the BSDF at any hit is
    // DiffuseBSDF(MaterialAt(hit).albedo), and integrators may shade with it directly
    // (PathIntegrator's specialised kernel) instead of through BSDF's variant.
    bool all_lambertian() const { return all_lambertian_; }
    // The albedo of the DiffuseBSDF at a hit when all_lambertian() (black on a light's own
    // surface, as BSDFAt's).
    Color LambertianAlbedoAt(const SurfaceHit& hit) const {
        const int64_t mi = MaterialIndexAt(hit);
        return mi < 0 ? Color(0.f) : materials_[size_t(mi)].albedo;
    }
    // Participating media (media/scene_media.cpp; docs/media.md). has_media: some material
    // bounds a medium; scenes without pay nothing (PathIntegrator::Li picks its kernel by it).
    bool has_media() const { return has_media_; }
    // Medium i is homogeneous below num_homogeneous_media(), a grid medium from there on.
    const HomogeneousMedium& medium(int32_t i) const { return media_[size_t(i)]; }
    int32_t num_homogeneous_media() const { return int32_t(media_.size()); }
    size_t num_grid_media() const { return grid_media_.size(); }
    const GridMedium* grid_medium(int32_t i) const {
        return i >= int32_t(media_.size()) ? &grid_media_[size_t(i) - media_.size()] : nullptr;
    }
    const MediumInterface& MediumInterfaceAt(const SurfaceHit& hit) const;
    bool IsInterfaceOnly(const SurfaceHit& hit) const;
    // The medium at p (-1: vacuum), from the side of the first boundary a ray from p meets.
    int32_t MediumAt(Vec3 p) const;
    // Beer-Lambert transmittance from p (a surface point with normal ng and error bound, or
    // a medium point: ng = 0) in `medium` to a light sample, through pure interfaces; zero
    // when any other surface blocks it.
    Color Transmittance(Vec3 p, float p_error, Vec3 ng, int32_t medium, const LightSample& ls) const;

    // Some material has a delta lobe (a smooth mirror, clear glass): transport radiosity's
    // form factors do not carry (radiosity_product.cpp picks the stochastic solver then).
    bool has_delta_surfaces() const {
        for (uint8_t d : material_may_have_delta_)
            if (d) return true;
        return false;
    }

    // A sphere around every triangle whose material has a delta lobe, where photons are
    // aimed (Jensen's projection maps): every light path that starts L S crosses it.
    // Radius 0 when there is none, or when something moves (the bound would have to hold
    // over the whole shutter).
    Vec3 delta_surfaces_center() const { return delta_center_; }
    float delta_surfaces_radius() const { return delta_radius_; }

    // Every triangle a ray can hit, world mesh first, then each instance's, in a fixed order
    // (the radiosity mesher's input): visit(mesh, prim, instance, world corners, sign), the
    // sign as TriangleVertices returns it (sign * Cross(p1 - p0, p2 - p0) faces as ng).
    template <typename Visit>
    void ForEachTriangle(Visit&& visit) const;

    size_t num_triangles() const { return num_triangles_; }
    // Bytes of texture texels held, mip-maps included.
    size_t texture_bytes() const { return textures_.TexelBytes(); }
    size_t num_curve_segments() const { return curve_material_.size(); }
    RTCScene embree_scene() const { return scene_; }  // for raw-Embree benchmarks
    size_t num_emitters() const { return emitters_.size(); }
    size_t num_instances() const { return instances_.size(); }
    // Some geometry moves or deforms during the shutter: camera samples then draw a time.
    bool has_motion() const { return !motion_m_.empty() || has_deformation_ || !light_motion_m_.empty(); }
    // Triangles stored (world mesh + one copy of each prototype), not counting instancing.
    size_t num_stored_triangles() const;

private:
    // A light kind's emitter functions (lights/*.h) read the scene's lights, frames and
    // materials directly: they are the scene's emitter queries, split by kind.
    template <typename>
    friend struct EmitterOf;
    friend struct AreaEmitterAnswers;      // what the area kinds' EmitterOf share
    friend struct InfiniteEmitterAnswers;  // what the kinds at infinity share
    void BuildGeometryAndLights(const SceneDesc& desc);
    void BuildMedia(const SceneDesc& desc);
    std::vector<HomogeneousMedium> media_;
    std::vector<GridMedium> grid_media_;
    bool has_media_ = false;
    void BoundDeltaSurfaces();
    void ReleaseEmbree() noexcept;
    struct Emitter {
        LightKind kind = kKindOf<TriangleLight>;
        uint32_t index = 0;  // into triangles (of `mesh`), or the lights of its kind
        float area = 0.f;    // triangle (world space) and sphere
        float one_minus_cos = 0.f;  // distant cone
        uint32_t mesh = 0;               // triangle: its mesh
        uint32_t instance = kNoInstance; // triangle of a prototype: the instance placing it
    };
    // One flat mesh: the world's (mesh 0, in scene_) or a prototype's (own BVH, own space).
    struct Mesh {
        RTCScene scene = nullptr;           // prototypes only
        const float* positions = nullptr;   // owned by Embree's buffers
        const uint32_t* indices = nullptr;
        size_t num_triangles = 0;
        std::vector<uint32_t> material;
        std::vector<float> normals;  // 9 per triangle, or empty
        std::vector<float> uvs;      // 6 per triangle, or empty
        // World mesh: the emitter of each triangle. Prototype: each triangle's index among
        // the prototype's emissive triangles (an instance adds its emitter base).
        std::vector<int32_t> emitter;
        uint32_t num_emissive = 0;
        // Deforming: the vertices of each time step (step_positions[0] == positions).
        uint32_t time_steps = 1;
        std::vector<const float*> step_positions;
    };
    struct Instance {
        uint32_t mesh = 0;
        float m[12];  // row-major 3x4 object-to-world
        float n[9];   // row-major inverse transpose of m's 3x3: transforms normals
        float orientation = 1.f;  // -1 for a mirroring transform
        int32_t emitter_base = -1;
        // Moving: time_steps matrices from motion_m_[12 first_step]; m is the first.
        uint32_t time_steps = 1;
        uint32_t first_step = 0;
    };
    // The instance's object-to-world matrix at this thread's shutter time: m, or the
    // interpolation of its time steps written to `scratch`. With `normals`, also the
    // matrix transforming its normals (n, or computed into `normals_scratch`).
    const float* InstanceMatrix(const Instance& in, float* scratch) const;
    const float* InstanceNormalMatrix(const Instance& in, const float* m, float* normals_scratch) const;
    // Corner c of triangle prim of a mesh at this thread's shutter time, in the mesh's space
    // (inline: every hit reads three; a still mesh pays one predictable branch).
    Vec3 MeshVertex(const Mesh& mesh, uint32_t prim, int corner) const {
        if (mesh.time_steps > 1) return DeformedVertex(mesh, prim, corner);
        const float* p = mesh.positions + 3 * size_t(mesh.indices[3 * size_t(prim) + corner]);
        return {p[0], p[1], p[2]};
    }
    Vec3 DeformedVertex(const Mesh& mesh, uint32_t prim, int corner) const;
    // A triangle emitter's area now (moving instances may scale it, deforming meshes reshape it).
    float EmitterArea(const Emitter& e) const;
    // After every world geometry ID (triangles, spheres, curves): instances share the top
    // level with them, and Embree refuses a scene that attaches two geometries by one ID.
    static constexpr uint32_t kFirstInstanceGeometry = kCurveGeometry + 1;
    static constexpr uint32_t kMaxTimeSteps = 129;  // Embree's own limit

    // A moving light's steps (time_steps 1: it stands still).
    struct LightMotion {
        uint32_t time_steps = 1;
        uint32_t first_step = 0;  // into light_motion_m_, 12 floats per step
    };
    void BuildLightMotion(const SceneDesc& desc);
    void BuildLightBVH(const std::vector<double>& power, SceneDesc::LightSelection selection);
    // The light's transform at this thread's shutter time, in scratch (12 floats) and its
    // normal matrix in n_scratch (9); nullptr when it stands still.
    const float* LightMotionAt(const LightMotion& motion, float* scratch, float* n_scratch) const {
        return motion.time_steps > 1 ? MovingLightAt(motion, scratch, n_scratch) : nullptr;
    }
    const float* MovingLightAt(const LightMotion& motion, float* scratch, float* n_scratch) const;
    // The light's transform now for emitter e (nullptr when nothing in the scene's lights
    // moves: static scenes skip the lookup).
    const float* EmitterMotionAt(const Emitter& e, float* scratch, float* n_scratch) const {
        return !kFullFeatures || light_motion_m_.empty() ? nullptr : LightMotionAt(MotionOf(e), scratch, n_scratch);
    }
    // A light at this thread's shutter time: maps between the world and the light as the
    // scene describes it (identity for a light that stands still).
    struct LightFrame {
        const float* m = nullptr;
        float m_scratch[12], n[9];
        Vec3 ToWorldDir(Vec3 d) const { return m ? Normalize(TransformVector(m, d)) : d; }
        Vec3 ToWorldPoint(Vec3 p) const { return m ? TransformPoint(m, p) : p; }
        Vec3 ToLightDir(Vec3 d) const { return m ? Normalize(TransformByInverse(n, d)) : d; }
        Vec3 ToLightPoint(Vec3 p) const { return m ? TransformByInverse(n, p - Vec3(m[3], m[7], m[11])) : p; }
    };
    // Emitter e's frame now; false when it stands still.
    bool FrameOf(const Emitter& e, LightFrame* f) const {
        f->m = EmitterMotionAt(e, f->m_scratch, f->n);
        return f->m != nullptr;
    }
    SphereLight SphereAt(uint32_t s) const;  // the sphere at this thread's shutter time
    const LightMotion& MotionOf(const Emitter& e) const;  // a still one for triangles

    Color EnvironmentRadiance(const Emitter& e, Vec3 origin, Vec3 dir, float* pdf) const;
    const char* kind_without_light_paths_ = nullptr;
    // Emitter e (a triangle; an element of emitters_) as its light kind sees it, in world
    // space at this thread's shutter time: from still_triangle_lights_ when nothing moves.
    TriangleLight TriangleLightOf(const Emitter& e) const;
    TriangleLight ResolveTriangleLight(const Emitter& e) const;
    void BuildMesh(Mesh* mesh, const float* positions, size_t num_vertices, const uint32_t* indices,
                   size_t num_triangles, const std::vector<uint32_t>& material, const std::vector<float>& normals,
                   const std::vector<float>& uvs, const std::vector<float>& motion_positions, RTCScene target,
                   uint32_t geom_id, const std::string& what);
    // World-space corners of triangle `prim` of `mesh` (through `instance` if any).
    // Returns the sign that makes orientation * Cross(p1 - p0, p2 - p0) the facing normal.
    float TriangleVertices(uint32_t mesh, uint32_t prim, uint32_t instance, Vec3 p[3]) const;
    Vec2 TriangleST(const Mesh& mesh, uint32_t prim, float b1, float b2) const;
    const Material& MaterialOf(uint32_t mesh, uint32_t prim) const {
        return materials_[meshes_[mesh].material[prim]];
    }
    // The material index of a surface hit (a triangle's or a curve segment's); -1 for a
    // light's own surface (a sphere light).
    int64_t MaterialIndexAt(const SurfaceHit& hit) const {
        if (hit.geom_id == kTriangleGeometry) return meshes_[hit.mesh].material[hit.prim_id];
        if (hit.geom_id == kCurveGeometry) return curve_material_[hit.prim_id];
        return -1;
    }
    void BuildCurves(const SceneDesc& desc, RTCDevice device);
    // Emitted radiance of a triangle's material at barycentrics (b1, b2), before sidedness.
    Color TriangleEmission(uint32_t mesh, uint32_t prim, float b1, float b2) const;
    void ApplyTextures(const Material& m, Vec2 st, const TextureFootprint& footprint, MaterialParams* p) const;
    void ApplyNormalMap(SurfaceHit* hit) const;

    RTCScene scene_ = nullptr;
    size_t num_triangles_ = 0;
    bool IntersectClosest(const Ray& ray, float t_near, float t_far, SurfaceHit* hit) const;
    // The hit record of Embree's closest hit `rh` (a hit) of `ray`: shared by the single-ray
    // and the packet queries, so that both give the same bits from the same Embree hit.
    bool FinishClosest(const Ray& ray, const RTCRayHit& rh, SurfaceHit* hit) const;
    // IntersectClosest's hit on a sphere light or a curve (kept out of the triangles' way).
    bool SphereOrCurveHit(const Ray& ray, const RTCRayHit& rh, SurfaceHit* hit) const;
    // Intersect without the normal map (shadow rays through cutouts need no shading).
    bool IntersectSurface(const Ray& ray, SurfaceHit* hit, float t_min, float t_max) const;
    bool IsCutoutHit(const SurfaceHit& hit) const;

    std::vector<Mesh> meshes_;
    std::vector<Instance> instances_;
    std::vector<float> motion_m_;  // time steps of moving instances, 12 floats each
    bool has_deformation_ = false;
    TextureSet textures_;
    std::vector<uint8_t> material_is_cutout_;
    std::vector<uint8_t> material_has_textures_;  // some slot other than -1: evaluate per hit
    std::vector<BSDF> material_bsdfs_;  // [2 m + mode]: the BSDF of an untextured material m
    std::vector<std::unique_ptr<PreviewSurfaceTable>> preview_tables_;  // read by material_bsdfs_
    std::vector<uint8_t> material_may_have_delta_;  // some hit of the material has a delta lobe
    bool has_cutouts_ = false;
    bool has_normal_maps_ = false;
    bool all_lambertian_ = true;
    std::vector<Material> materials_;
    std::vector<LightShaping> emission_shapings_;
    // The shaping of a triangle emitter's material about its emitting normal n (or the
    // light's axis), toward w.
    Color EmissionShaping(const Material& m, Vec3 n, Vec3 w) const {
        if (m.emission_shaping < 0) return Color(1.f);
        const LightShaping& s = emission_shapings_[m.emission_shaping];
        return s.FactorAbout(s.about_axis ? s.axis : n, w);
    }
    template <typename Kind>
    using LightsOf = std::vector<Kind>;  // the dome: one, active or not
    template <typename Kind>
    using MotionsOf = std::vector<LightMotion>;  // one per light of a kind that moves
    PerLightKind<LightsOf> lights_;
    PerLightKind<MotionsOf> light_motions_;
    std::vector<float> light_motion_m_;
    Vec3 scene_center_;
    Vec3 delta_center_;
    float delta_radius_ = 0.f;
    float scene_radius_ = 1.f;
    int splat_exponent_ = 0;  // bounding sphere: the power of lights at infinity
    std::vector<Emitter> emitters_;
    std::vector<TriangleLight> still_triangle_lights_;  // per emitter (triangles only); empty when something moves
    std::vector<uint32_t> environment_lights_;  // emitter indices of distant cones and the dome
    std::vector<int32_t> sphere_emitter_;
    std::vector<uint32_t> curve_material_;  // per curve segment
    std::vector<float> curve_radius_;       // per curve control point (the hit's error bound)
    std::vector<uint32_t> curve_first_;     // per curve segment: its first control point
    LightSampler light_sampler_;
    // SampleLight: the BVH over still area emitters, chosen with probability light_bvh_share_
    // (their share of the power), and the rest by power through other_lights_.
    BVHLightSampler light_bvh_;
    float light_bvh_share_ = 0.f;
    LightSampler other_lights_;
    std::vector<uint32_t> other_light_ids_;   // other_lights_ index -> emitter
    std::vector<int32_t> other_light_index_;  // emitter -> other_lights_ index, -1 if in the BVH
    bool SampleAnyLight(float u, Vec3 p, Vec3 n, uint32_t* light, float* pmf) const;
    // One draw between the light BVH, with probability `share`, and the power table `other`
    // over the lights outside it (numbered as other_light_ids_).
    bool SampleBVHOrTable(float u, Vec3 p, Vec3 n, float share, const LightSampler& other, uint32_t* light,
                          float* pmf) const;
    float AnyLightPmf(Vec3 p, Vec3 n, uint32_t light) const;
    // Light linking: the table, and each emitter's link (-1: the default).
    bool has_light_links_ = false;
    size_t num_linked_lights_ = 0;
    LightLinkTable light_links_;
    std::vector<int32_t> emitter_link_;
    void BuildLightLinks(const SceneDesc& desc);
    // Per link group, the lights that illuminate it, chosen by power: among all of them
    // (`all`, without a light BVH), or among those outside the BVH (`other`, taken with
    // probability 1 - bvh_share). The BVH holds only lights without links, which
    // illuminate every group: it is shared, and never chooses a light a group must not see.
    struct LinkGroupLights {
        LightSampler all, other;
        float bvh_share = 0.f;
    };
    std::vector<LinkGroupLights> group_lights_;
    void BuildGroupLights(const std::vector<double>& power);
    bool SampleLinkedLight(float u, Vec3 p, Vec3 n, uint32_t* light, float* pmf, uint32_t group) const;
    float LinkedLightPmf(Vec3 p, Vec3 n, uint32_t light, uint32_t group) const;
    bool UnoccludedPastUnlinked(int32_t link, Vec3 p, float p_error, Vec3 ng, const LightSample& ls) const;
};

template <typename Visit>
void Scene::ForEachEnvironmentLight(Vec3 origin, Vec3 dir, Visit&& visit) const {
    for (uint32_t i : environment_lights_) {
        float pdf = 0.f;
        Color L = EnvironmentRadiance(emitters_[i], origin, dir, &pdf);
        if (!IsBlack(L)) visit(i, L, pdf);
    }
}

template <typename Visit>
void Scene::ForEachTriangle(Visit&& visit) const {
    Vec3 p[3];
    for (uint32_t prim = 0; prim < meshes_[0].num_triangles; ++prim) {
        const float sign = TriangleVertices(0, prim, kNoInstance, p);
        visit(0u, prim, kNoInstance, p, sign);
    }
    for (uint32_t i = 0; i < instances_.size(); ++i) {
        const uint32_t mesh = instances_[i].mesh;
        for (uint32_t prim = 0; prim < meshes_[mesh].num_triangles; ++prim) {
            const float sign = TriangleVertices(mesh, prim, i, p);
            visit(mesh, prim, i, p, sign);
        }
    }
}

// The process-wide Embree device (created on first use, thread-safe).
RTCDevice EmbreeDevice();
// Bytes the Embree device holds now (its memory monitor's running sum): BVHs and buffers.
int64_t EmbreeMemoryBytes();

}  // namespace tessera
