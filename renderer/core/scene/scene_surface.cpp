// Scene queries at a ray's hit: intersection (with cutout presence), occlusion, the
// triangle's geometry, textures and normal maps, and the material and BSDF there. The
// Scene is built in scene.cpp; its emitters are sampled in scene_emitters.cpp.
#include "scene.h"

#include <algorithm>

#include <cstring>
#include <limits>

#include "ray_counters.h"
#include "sampling.h"

namespace tessera {

namespace {

// A uniform number in [0, 1) from a hit's position and triangle: the presence decision of
// a partially present surface. Rays of different samples meet a surface at different
// points, so over samples the pass-through fraction is 1 - opacity, without a sampler
// dimension (shadow rays have none) and the same for every integrator.
float PresenceHash(const SurfaceHit& hit) {
    auto bits = [](float f) { uint32_t u; std::memcpy(&u, &f, 4); return uint64_t(u); };
    uint64_t h = bits(hit.p.x) ^ (bits(hit.p.y) << 21) ^ (bits(hit.p.z) << 42) ^
                 (uint64_t(hit.prim_id) * 0x9E3779B97F4A7C15ull) ^ (uint64_t(hit.mesh) << 32);
    h ^= h >> 33; h *= 0xFF51AFD7ED558CCDull; h ^= h >> 33; h *= 0xC4CEB9FE1A85EC53ull; h ^= h >> 33;
    return float(h >> 40) * 0x1p-24f;
}

}  // namespace

namespace {

inline Vec3 LocalVertex(const float* positions, const uint32_t* indices, uint32_t tri, int corner) {
    const float* p = positions + 3 * size_t(indices[3 * size_t(tri) + corner]);
    return {p[0], p[1], p[2]};
}
// The error bound of TransformPoint(m, p) for p known within p_error per axis: the
// propagated error plus the rounding of the 3 products and 3 sums per row (pbrt-v4 6.8.6).
inline float TransformedPointError(const float* m, Vec3 p, float p_error) {
    float bound = 0.f;
    for (int r = 0; r < 3; ++r) {
        const float* row = m + 4 * r;
        const float abs_row = std::abs(row[0]) + std::abs(row[1]) + std::abs(row[2]);
        const float magnitude = std::abs(row[0] * p.x) + std::abs(row[1] * p.y) + std::abs(row[2] * p.z) +
                                std::abs(row[3]);
        bound = std::max(bound, (1.f + Gamma(3)) * abs_row * p_error + Gamma(3) * magnitude);
    }
    return bound;
}

}  // namespace

Vec3 Scene::DeformedVertex(const Mesh& mesh, uint32_t prim, int corner) const {
    uint32_t k;
    float f;
    ShutterSegment(mesh.time_steps, &k, &f);
    const Vec3 a = LocalVertex(mesh.step_positions[k], mesh.indices, prim, corner),
               b = LocalVertex(mesh.step_positions[k + 1], mesh.indices, prim, corner);
    return a * (1.f - f) + b * f;
}

const float* Scene::InstanceMatrix(const Instance& in, float* scratch) const {
    if (in.time_steps <= 1) return in.m;
    return MatrixAtShutterTime(&motion_m_[12 * size_t(in.first_step)], in.time_steps, scratch);
}

const float* Scene::InstanceNormalMatrix(const Instance& in, const float* m, float* normals_scratch) const {
    if (m == in.m) return in.n;
    // A singular instant (a scale through zero) keeps the first step's normals.
    std::copy(in.n, in.n + 9, normals_scratch);
    NormalMatrixOf(m, normals_scratch);
    return normals_scratch;
}

float Scene::TriangleVertices(uint32_t mesh, uint32_t prim, uint32_t instance, Vec3 p[3]) const {
    const Mesh& m = meshes_[mesh];
    float scratch[12];
    const float* xf = kFullFeatures && instance != kNoInstance ? InstanceMatrix(instances_[instance], scratch) : nullptr;
    for (int c = 0; c < 3; ++c) {
        p[c] = MeshVertex(m, prim, c);
        if (xf) p[c] = TransformPoint(xf, p[c]);
    }
    // A mirroring instance transform reverses the winding of the transformed corners; the
    // flattened copy reverses its corner order instead, so the side a triangle faces is
    // the same either way: Cross(p1 - p0, p2 - p0) times this sign.
    return kFullFeatures && instance != kNoInstance ? instances_[instance].orientation : 1.f;
}

Vec2 Scene::TriangleST(const Mesh& mesh, uint32_t prim, float b1, float b2) const {
    if (mesh.uvs.empty()) return {};
    const float* uv = &mesh.uvs[6 * size_t(prim)];
    const float b0 = 1.f - b1 - b2;
    return {uv[0] * b0 + uv[2] * b1 + uv[4] * b2, uv[1] * b0 + uv[3] * b1 + uv[5] * b2};
}

Color Scene::TriangleEmission(uint32_t mesh, uint32_t prim, float b1, float b2) const {
    const Material& m = MaterialOf(mesh, prim);
    const int32_t t = m.textures[kSlotEmissiveColor];
    if (!kFullFeatures || t < 0) return m.emission;
    const Color c = textures_.EvaluateColor(uint32_t(t), TriangleST(meshes_[mesh], prim, b1, b2));
    return {std::max(0.f, c.x), std::max(0.f, c.y), std::max(0.f, c.z)};
}

void Scene::ApplyTextures(const Material& m, Vec2 st, const TextureFootprint& footprint, MaterialParams* p) const {
    auto color = [&](TextureSlot slot, Color* out) {
        if (m.textures[slot] >= 0) *out = textures_.EvaluateColor(uint32_t(m.textures[slot]), st, footprint);
    };
    auto scalar = [&](TextureSlot slot, float* out) {
        if (m.textures[slot] >= 0) *out = textures_.EvaluateFloat(uint32_t(m.textures[slot]), st, footprint);
    };
    // Emission and opacity stay point lookups: light sampling (TriangleEmission) and
    // presence (IsCutoutHit) see them without a footprint, and a BSDF-hit and a light
    // sample must agree on the same surface's values for MIS.
    auto point_color = [&](TextureSlot slot, Color* out) {
        if (m.textures[slot] >= 0) *out = textures_.EvaluateColor(uint32_t(m.textures[slot]), st);
    };
    auto point_scalar = [&](TextureSlot slot, float* out) {
        if (m.textures[slot] >= 0) *out = textures_.EvaluateFloat(uint32_t(m.textures[slot]), st);
    };
    // Out-of-range values (a texture scaled past 1, say) are sanitised by
    // MakePreviewSurfaceBSDF like constant inputs are.
    color(kSlotDiffuseColor, &p->diffuse_color);
    point_color(kSlotEmissiveColor, &p->emissive_color);
    color(kSlotSpecularColor, &p->specular_color);
    scalar(kSlotMetallic, &p->metallic);
    scalar(kSlotRoughness, &p->roughness);
    scalar(kSlotClearcoat, &p->clearcoat);
    scalar(kSlotClearcoatRoughness, &p->clearcoat_roughness);
    point_scalar(kSlotOpacity, &p->opacity);
    scalar(kSlotIor, &p->ior);
}

TextureFootprint Scene::FootprintAt(const SurfaceHit& hit) const {
    const TextureFootprintCamera* cam = tls_footprint_camera;
    if (!cam || hit.geom_id != kTriangleGeometry) return {};
    const Mesh& mesh = meshes_[hit.mesh];
    if (mesh.uvs.empty()) return {};
    // The pixel's ray cone at the hit: its width across the ray, stretched by 1 / cos along
    // the ray's projection onto the surface (the footprint's long axis at grazing angles).
    Vec3 r = cam->forward;
    float width = cam->pixel_width;
    if (!cam->orthographic) {
        const Vec3 to = hit.p - cam->origin;
        const float dist = Length(to);
        if (!(dist > 0.f)) return {};
        r = to / dist;
        width = dist * cam->pixel_angle;
    }
    if (!(width > 0.f) || !std::isfinite(width)) return {};
    const Vec3 n = hit.ng;
    const float cos_theta = std::max(std::abs(Dot(r, n)), 1e-3f);
    const Vec3 along = r - n * Dot(r, n);
    const float along_length = Length(along);
    Vec3 u;
    if (along_length > 1e-6f) {
        u = along / along_length;
    } else {  // head-on: any direction in the surface
        u = Normalize(Cross(n, std::abs(n.x) < 0.9f ? Vec3{1.f, 0.f, 0.f} : Vec3{0.f, 1.f, 0.f}));
    }
    const Vec3 v = Cross(n, u);
    const Vec3 a = u * (width / cos_theta), b = v * width;
    // World offsets in the triangle's plane to st: x = alpha e1 + beta e2 solved through the
    // edges' Gram matrix, then st moves by alpha duv1 + beta duv2.
    Vec3 p[3];
    TriangleVertices(hit.mesh, hit.prim_id, hit.instance, p);
    const Vec3 e1 = p[1] - p[0], e2 = p[2] - p[0];
    const float g11 = Dot(e1, e1), g12 = Dot(e1, e2), g22 = Dot(e2, e2);
    const float det = g11 * g22 - g12 * g12;
    if (!(det > 0.f) || !std::isfinite(det)) return {};
    const float* uv = &mesh.uvs[6 * size_t(hit.prim_id)];
    const float du1 = uv[2] - uv[0], dv1 = uv[3] - uv[1], du2 = uv[4] - uv[0], dv2 = uv[5] - uv[1];
    const auto to_st = [&](Vec3 x) {
        const float p1 = Dot(x, e1), p2 = Dot(x, e2);
        const float alpha = (g22 * p1 - g12 * p2) / det, beta = (g11 * p2 - g12 * p1) / det;
        return Vec2{alpha * du1 + beta * du2, alpha * dv1 + beta * dv2};
    };
    TextureFootprint f{to_st(a), to_st(b)};
    if (!std::isfinite(f.dx.x) || !std::isfinite(f.dx.y) || !std::isfinite(f.dy.x) || !std::isfinite(f.dy.y))
        return {};
    return f;
}

void Scene::ApplyNormalMap(SurfaceHit* hit) const {
    if (hit->geom_id != kTriangleGeometry) return;  // curves have no st, so no tangent frame
    const Material& mat = MaterialOf(hit->mesh, hit->prim_id);
    const int32_t tex = mat.textures[kSlotNormal];
    const Mesh& mesh = meshes_[hit->mesh];
    if (tex < 0 || mesh.uvs.empty()) return;  // no st: no tangent frame, the map cannot apply
    // Tangent frame from the st parameterisation: dp/ds and dp/dt of the triangle (they do
    // not depend on the corner order, so flattened and instanced copies agree).
    const uint32_t prim = hit->prim_id;
    Vec3 p[3];
    for (int c = 0; c < 3; ++c) p[c] = MeshVertex(mesh, prim, c);
    const float* uv = &mesh.uvs[6 * size_t(prim)];
    const Vec3 e1 = p[1] - p[0], e2 = p[2] - p[0];
    const float du1 = uv[2] - uv[0], dv1 = uv[3] - uv[1], du2 = uv[4] - uv[0], dv2 = uv[5] - uv[1];
    const float det = du1 * dv2 - du2 * dv1;
    if (!(std::abs(det) > 1e-20f)) return;  // degenerate st: no frame
    Vec3 dpds = (e1 * dv2 - e2 * dv1) / det, dpdt = (e2 * du1 - e1 * du2) / det;
    if (hit->instance != kNoInstance) {
        float scratch[12];
        const float* xf = InstanceMatrix(instances_[hit->instance], scratch);
        dpds = TransformVector(xf, dpds);
        dpdt = TransformVector(xf, dpdt);
    }
    const Vec3 n = hit->ns;
    Vec3 t = dpds - n * Dot(n, dpds);
    const float tl = Length(t);
    if (!(tl > 0.f) || !std::isfinite(tl)) return;
    t = t / tl;
    Vec3 b = Cross(n, t);
    if (Dot(b, dpdt) < 0.f) b = -b;  // mirrored st: keep the map's +y along +t
    const Color m = textures_.EvaluateColor(uint32_t(tex), hit->st);
    const Vec3 mapped = t * m.x + b * m.y + n * m.z;
    const float len = Length(mapped);
    // A normal that turns below the geometric surface cannot shade it (SidesAgree would
    // reject most scattering); keep the unperturbed shading normal there.
    if (!(len > 0.f) || !std::isfinite(len) || !(Dot(mapped, hit->ng) > 1e-4f * len)) return;
    hit->ns = mapped / len;
}

bool Scene::IsCutoutHit(const SurfaceHit& hit) const {
    const int64_t mi = MaterialIndexAt(hit);
    if (mi < 0) return false;
    if (!material_is_cutout_[mi]) return false;
    const Material& m = materials_[mi];
    const int32_t t = m.textures[kSlotOpacity];
    if (IsPresenceMode(*m.preview)) {
        const float opacity = t < 0 ? m.preview->opacity : textures_.EvaluateFloat(uint32_t(t), hit.st);
        return PresenceHash(hit) >= opacity;
    }
    return t < 0 || IsCutout(*m.preview, textures_.EvaluateFloat(uint32_t(t), hit.st));
}

bool Scene::IntersectSurface(const Ray& ray, SurfaceHit* hit, float t_min, float t_max) const {
    if (!kFullFeatures || !has_cutouts_) return IntersectClosest(ray, t_min, t_max, hit);
    // Step through cutout surfaces. Each step restarts just past the previous hit, so a
    // ray crosses at most as many cutout layers as lie along it.
    float t_near = t_min;
    for (int layer = 0; layer < 1024; ++layer) {
        if (!IntersectClosest(ray, t_near, t_max, hit)) return false;
        if (!IsCutoutHit(*hit)) return true;
        t_near = NextFloatUp(hit->t) * (1.f + 1e-6f);
    }
    return false;
}

bool Scene::SphereOrCurveHit(const Ray& ray, const RTCRayHit& rh, SurfaceHit* hit) const {
    if (rh.hit.geomID == kSphereGeometry) {
        const SphereLight s = SphereAt(rh.hit.primID);
        Vec3 p = ray.o + ray.d * rh.ray.tfar;
        hit->geom_id = kSphereGeometry;
        hit->mesh = 0;
        hit->instance = kNoInstance;
        hit->ng = Normalize(p - s.center);
        hit->ns = hit->ng;
        hit->p = s.center + hit->ng * s.radius;
        hit->p_error = Gamma(5) * (MaxAbsComponent(s.center) + s.radius);
        hit->st = {};
        return true;
    }
    // A round curve: Embree's Ng is the swept surface's normal there (outward). The
    // point comes from o + t d; its error bound covers that and Embree's curve test,
    // which is iterative and far less exact than the triangle test: a thousandth of
    // the local radius (offsetting by it keeps a reflected ray off the strand it left
    // without letting it pass through a thin one).
    const uint32_t first = curve_first_[rh.hit.primID];
    const float r = curve_radius_[first] * (1.f - rh.hit.u) + curve_radius_[first + 1] * rh.hit.u;
    const Vec3 p = ray.o + ray.d * rh.ray.tfar;
    Vec3 ng(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z);
    const float len = Length(ng);
    hit->geom_id = kCurveGeometry;
    hit->mesh = 0;
    hit->instance = kNoInstance;
    hit->ng = len > 0.f && std::isfinite(len) ? ng / len : -ray.d;
    hit->ns = hit->ng;
    hit->p = p;
    hit->p_error = Gamma(5) * (MaxAbsComponent(ray.o) + MaxAbsComponent(ray.d * rh.ray.tfar)) + 1e-3f * r;
    hit->st = {};
    return true;
}

bool Scene::IntersectClosest(const Ray& ray, float t_near, float t_far, SurfaceHit* hit) const {
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    RTCRayHit rh;
    rh.ray.org_x = ray.o.x;
    rh.ray.org_y = ray.o.y;
    rh.ray.org_z = ray.o.z;
    rh.ray.dir_x = ray.d.x;
    rh.ray.dir_y = ray.d.y;
    rh.ray.dir_z = ray.d.z;
    rh.ray.tnear = t_near;
    rh.ray.tfar = t_far;
    rh.ray.time = tls_shutter_time;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    ++tls_ray_counters.closest;
    rtcIntersect1(scene_, &context, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
    return FinishClosest(ray, rh, hit);
}

bool Scene::FinishClosest(const Ray& ray, const RTCRayHit& rh, SurfaceHit* hit) const {
    hit->t = rh.ray.tfar;
    hit->prim_id = rh.hit.primID;
    hit->b1 = rh.hit.u;
    hit->b2 = rh.hit.v;
    const uint32_t inst = rh.hit.instID[0];
    if (kFullFeatures && inst == RTC_INVALID_GEOMETRY_ID && rh.hit.geomID != kTriangleGeometry) [[unlikely]]
        return SphereOrCurveHit(ray, rh, hit);
    hit->geom_id = kTriangleGeometry;
    hit->instance = !kFullFeatures || inst == RTC_INVALID_GEOMETRY_ID ? kNoInstance : inst - kFirstInstanceGeometry;
    hit->mesh = hit->instance == kNoInstance ? 0 : instances_[hit->instance].mesh;
    const Mesh& mesh = meshes_[hit->mesh];
    const uint32_t prim = rh.hit.primID;
    // Recompute the hit point from barycentrics: smaller error than o + t d far away.
    const Vec3 p0 = MeshVertex(mesh, prim, 0), p1 = MeshVertex(mesh, prim, 1), p2 = MeshVertex(mesh, prim, 2);
    const float u = rh.hit.u, v = rh.hit.v;
    float p_error;
    Vec3 p = TrianglePoint(p0, p1, p2, u, v, &p_error);
    // A deforming mesh's corners are interpolated between steps (2 products and a sum per
    // coordinate, here and in Embree): Embree's triangle may differ from ours by that much.
    if (kFullFeatures && mesh.time_steps > 1)
        p_error += Gamma(3) * std::max({MaxAbsComponent(p0), MaxAbsComponent(p1), MaxAbsComponent(p2)});
    Vec3 ng = Cross(p1 - p0, p2 - p0);
    Vec3 ns(0.f);
    if (!mesh.normals.empty()) {
        const float* n = &mesh.normals[9 * size_t(prim)];
        ns = Vec3(n[0], n[1], n[2]) * (1.f - u - v) + Vec3(n[3], n[4], n[5]) * u + Vec3(n[6], n[7], n[8]) * v;
    }
    if (kFullFeatures && hit->instance != kNoInstance) {
        // Points by the transform, normals by its inverse transpose. With a mirroring
        // transform the inverse transpose keeps the normal on the side the flattened copy
        // (whose winding is reversed) faces.
        const Instance& in = instances_[hit->instance];
        float m_scratch[12], n_scratch[9];
        const float* m = InstanceMatrix(in, m_scratch);
        const float* n = InstanceNormalMatrix(in, m, n_scratch);
        p_error = TransformedPointError(m, p, p_error);
        p = TransformPoint(m, p);
        ng = TransformNormal(n, ng);
        ns = TransformNormal(n, ns);
    }
    hit->p = p;
    hit->p_error = p_error;
    hit->ng = Normalize(ng);
    hit->ns = hit->ng;
    if (!mesh.normals.empty()) {
        float len = Length(ns);
        // Degenerate or non-finite authored normals fall back to the facet's.
        if (len > 1e-6f && std::isfinite(len)) hit->ns = Dot(ns, hit->ng) >= 0.f ? ns / len : -ns / len;
    }
    hit->st = kFullFeatures ? TriangleST(mesh, prim, u, v) : Vec2{};
    return true;
}

bool Scene::Occluded(Vec3 origin, Vec3 dir, float t_far) const {
    if (kFullFeatures && has_cutouts_) {
        SurfaceHit hit;
        return IntersectSurface({origin, dir}, &hit, 0.f, t_far) && hit.t < t_far;
    }
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    RTCRay ray;
    ray.org_x = origin.x;
    ray.org_y = origin.y;
    ray.org_z = origin.z;
    ray.dir_x = dir.x;
    ray.dir_y = dir.y;
    ray.dir_z = dir.z;
    ray.tnear = 0.f;
    ray.tfar = t_far;
    ray.time = tls_shutter_time;
    ray.mask = 0xFFFFFFFFu;
    ray.id = 0;
    ray.flags = 0;
    ++tls_ray_counters.shadow;
    rtcOccluded1(scene_, &context, &ray);
    return ray.tfar < 0.f;  // Embree sets tfar = -inf on a hit
}

bool Scene::Unoccluded(Vec3 p0, float p0_error, Vec3 n0, Vec3 p1, float p1_error, Vec3 n1) const {
    const Vec3 from = OffsetRayOrigin(p0, p0_error, n0, p1 - p0);
    const Vec3 to = OffsetRayOrigin(p1, p1_error, n1, from - p1);
    const Vec3 d = to - from;
    const float len = Length(d);
    if (!(len > 0.f)) return false;
    // Both ends already sit off their surfaces; the shortening only keeps Embree's own
    // rounding of t from reaching the far one.
    return !Occluded(from, d / len, len * (1.f - kShadowEpsilon));
}

bool Scene::Unoccluded(Vec3 p, float p_error, Vec3 ng, const LightSample& ls) const {
    if (std::isinf(ls.distance))
        return !Occluded(OffsetRayOrigin(p, p_error, ng, ls.wi), ls.wi, std::numeric_limits<float>::infinity());
    return Unoccluded(p, p_error, ng, ls.p, ls.p_error, ls.n);
}

bool Scene::UnoccludedPastUnlinked(int32_t link, Vec3 p, float p_error, Vec3 ng, const LightSample& ls) const {
    Vec3 from, dir;
    float t_far;
    if (std::isinf(ls.distance)) {
        from = OffsetRayOrigin(p, p_error, ng, ls.wi);
        dir = ls.wi;
        t_far = std::numeric_limits<float>::infinity();
    } else {
        // The two-ended offsets of Unoccluded, then its shortened segment.
        from = OffsetRayOrigin(p, p_error, ng, ls.p - p);
        const Vec3 to = OffsetRayOrigin(ls.p, ls.p_error, ls.n, from - ls.p);
        const Vec3 d = to - from;
        const float len = Length(d);
        if (!(len > 0.f)) return false;
        dir = d / len;
        t_far = len * (1.f - kShadowEpsilon);
    }
    // Step through the surfaces that do not cast this light's shadows, as IntersectSurface
    // steps through cutouts: each step restarts just past the previous hit.
    const Ray ray{from, dir};
    float t_near = 0.f;
    for (int layer = 0; layer < 1024; ++layer) {
        SurfaceHit hit;
        ++tls_ray_counters.shadow;
        if (!IntersectSurface(ray, &hit, t_near, t_far) || !(hit.t < t_far)) return true;
        if (light_links_.CastsShadow(link, LinkGroupAt(hit))) return false;
        t_near = NextFloatUp(hit.t) * (1.f + 1e-6f);
    }
    return false;
}

const Material& Scene::MaterialAt(const SurfaceHit& hit) const {
    static const Material kLightSurface{Color(0.f), Color(0.f), false, std::nullopt};
    const int64_t mi = MaterialIndexAt(hit);
    return mi >= 0 ? materials_[mi] : kLightSurface;
}

BSDF Scene::BSDFAt(const SurfaceHit& hit, TransportMode mode) const {
    const int64_t mi = MaterialIndexAt(hit);
    if (mi < 0) return BSDF();
    const Material& m = materials_[mi];
    if (!kFullFeatures || !m.preview || !material_has_textures_[mi])
        return material_bsdfs_[2 * size_t(mi) + size_t(mode)];
    MaterialParams p = *m.preview;  // a copy on the stack, textured inputs evaluated at st
    ApplyTextures(m, hit.st, FootprintAt(hit), &p);
    return MakePreviewSurfaceBSDF(p, mode);
}

}  // namespace tessera
