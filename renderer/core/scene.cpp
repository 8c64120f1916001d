#include "scene.h"

#include <limits>
#include <stdexcept>
#include <string>

#include "ray_counters.h"
#include "sampling.h"

namespace tessera {

namespace {

void CheckDevice(RTCDevice device, const char* what) {
    RTCError err = rtcGetDeviceError(device);
    if (err != RTC_ERROR_NONE)
        throw std::runtime_error(std::string("Embree error ") + std::to_string(int(err)) + " in " + what);
}

bool IsNonNegativeFinite(Color c) {
    return IsFinite(c) && c.x >= 0.f && c.y >= 0.f && c.z >= 0.f;
}

}  // namespace

RTCDevice EmbreeDevice() {
    static RTCDevice device = [] {
        RTCDevice d = rtcNewDevice("verbose=0");
        if (!d) throw std::runtime_error("cannot create the Embree device");
        return d;
    }();
    return device;
}

Scene::Scene(const SceneDesc& desc)
    : triangle_material_(desc.triangle_material),
      shading_normals_(desc.shading_normals),
      materials_(desc.materials),
      spheres_(desc.sphere_lights),
      points_(desc.point_lights),
      distants_(desc.distant_lights),
      dome_radiance_(desc.dome_radiance) {
    if (desc.positions.size() % 3 != 0) throw std::invalid_argument("positions must hold 3 floats per vertex");
    if (desc.indices.size() % 3 != 0) throw std::invalid_argument("indices must hold 3 per triangle");
    const size_t num_vertices = desc.positions.size() / 3;
    num_triangles_ = desc.indices.size() / 3;
    if (triangle_material_.size() != num_triangles_)
        throw std::invalid_argument("triangle_material must have one entry per triangle");
    if (num_vertices > 0xFFFFFFFFull) throw std::invalid_argument("too many vertices");
    if (!shading_normals_.empty() && shading_normals_.size() != 9 * num_triangles_)
        throw std::invalid_argument("shading_normals must hold 3 normals per triangle");
    for (size_t i = 0; i < desc.positions.size(); ++i)
        if (!std::isfinite(desc.positions[i]))
            throw std::invalid_argument("vertex " + std::to_string(i / 3) + " has a non-finite coordinate");
    for (size_t i = 0; i < desc.indices.size(); ++i)
        if (desc.indices[i] >= num_vertices)
            throw std::invalid_argument("triangle " + std::to_string(i / 3) + " indexes vertex " +
                                        std::to_string(desc.indices[i]) + " of " + std::to_string(num_vertices));
    for (size_t t = 0; t < num_triangles_; ++t)
        if (triangle_material_[t] >= materials_.size())
            throw std::invalid_argument("triangle " + std::to_string(t) + " has material " +
                                        std::to_string(triangle_material_[t]) + " of " +
                                        std::to_string(materials_.size()));
    for (size_t m = 0; m < materials_.size(); ++m) {
        if (!IsNonNegativeFinite(materials_[m].albedo) || !IsNonNegativeFinite(materials_[m].emission) ||
            MaxComponent(materials_[m].albedo) > 1.f)
            throw std::invalid_argument("material " + std::to_string(m) +
                                        ": albedo must be in [0, 1] and emission finite and >= 0");
        // Cutout by the material's own opacity (textured opacity will refine this per hit).
        const auto& pv = materials_[m].preview;
        material_is_cutout_.push_back(pv && IsCutout(*pv, pv->opacity));
        has_cutouts_ = has_cutouts_ || material_is_cutout_.back();
    }
    for (size_t s = 0; s < spheres_.size(); ++s)
        if (!IsFinite(spheres_[s].center) || !(spheres_[s].radius > 0.f) || !std::isfinite(spheres_[s].radius) ||
            !IsNonNegativeFinite(spheres_[s].radiance))
            throw std::invalid_argument("sphere light " + std::to_string(s) + " has a bad centre, radius or radiance");
    for (size_t i = 0; i < points_.size(); ++i)
        if (!IsFinite(points_[i].position) || !IsNonNegativeFinite(points_[i].intensity))
            throw std::invalid_argument("point light " + std::to_string(i) + " has a bad position or intensity");
    for (size_t i = 0; i < distants_.size(); ++i) {
        DistantLight& d = distants_[i];
        float len = Length(d.direction);
        if (!IsFinite(d.direction) || !(len > 0.f) || !(d.half_angle >= 0.f) || !(d.half_angle < 0.5f * kPi) ||
            !IsNonNegativeFinite(d.radiance))
            throw std::invalid_argument("distant light " + std::to_string(i) +
                                        " needs a direction, a half angle in [0, pi/2) and radiance >= 0");
        d.direction = d.direction / len;
    }
    if (!IsNonNegativeFinite(dome_radiance_)) throw std::invalid_argument("dome radiance must be finite and >= 0");
    if (desc.dome_width > 0) {
        if (desc.dome_rgb.size() != size_t(desc.dome_width) * desc.dome_height * 3 || desc.dome_height == 0)
            throw std::invalid_argument("dome texture size does not match its pixels");
        for (float v : desc.dome_rgb)
            if (!(v >= 0.f) || !std::isfinite(v)) throw std::invalid_argument("dome texture has negative or non-finite texels");
        dome_w_ = desc.dome_width;
        dome_h_ = desc.dome_height;
        dome_rgb_ = desc.dome_rgb;
        std::copy(desc.dome_world_to_light, desc.dome_world_to_light + 9, dome_m_);
        std::vector<float> weights(size_t(dome_w_) * dome_h_);
        for (uint32_t y = 0; y < dome_h_; ++y) {
            const float sin_theta = std::sin(kPi * (float(y) + 0.5f) / float(dome_h_));
            for (uint32_t x = 0; x < dome_w_; ++x) {
                const float* t = &dome_rgb_[3 * (size_t(y) * dome_w_ + x)];
                weights[size_t(y) * dome_w_ + x] = Luminance(Color(t[0], t[1], t[2])) * sin_theta;
            }
        }
        dome_distribution_ = Distribution2D(weights, dome_w_, dome_h_);
    }

    RTCDevice device = EmbreeDevice();
    scene_ = rtcNewScene(device);
    // Watertight triangle test: a closed mesh must not leak light through its edges.
    rtcSetSceneFlags(scene_, RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(scene_, RTC_BUILD_QUALITY_HIGH);

    {
        RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
        // Embree may read 16 bytes from the last vertex, hence one vertex of padding.
        auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                               3 * sizeof(float), num_vertices + 1));
        auto* ib = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                                  3 * sizeof(uint32_t), num_triangles_));
        CheckDevice(device, "allocating triangle buffers");
        std::copy(desc.positions.begin(), desc.positions.end(), vb);
        vb[3 * num_vertices] = vb[3 * num_vertices + 1] = vb[3 * num_vertices + 2] = 0.f;
        std::copy(desc.indices.begin(), desc.indices.end(), ib);
        positions_ = vb;
        indices_ = ib;
        rtcCommitGeometry(geom);
        uint32_t id = rtcAttachGeometry(scene_, geom);
        rtcReleaseGeometry(geom);
        if (id != kTriangleGeometry) throw std::logic_error("unexpected triangle geometry id");
    }
    if (!spheres_.empty()) {
        RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_SPHERE_POINT);
        auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4,
                                                               4 * sizeof(float), spheres_.size()));
        CheckDevice(device, "allocating sphere buffers");
        for (size_t s = 0; s < spheres_.size(); ++s) {
            vb[4 * s + 0] = spheres_[s].center.x;
            vb[4 * s + 1] = spheres_[s].center.y;
            vb[4 * s + 2] = spheres_[s].center.z;
            vb[4 * s + 3] = spheres_[s].radius;
        }
        rtcCommitGeometry(geom);
        uint32_t id = rtcAttachGeometry(scene_, geom);
        rtcReleaseGeometry(geom);
        if (id != kSphereGeometry) throw std::logic_error("unexpected sphere geometry id");
    }
    rtcCommitScene(scene_);
    CheckDevice(device, "building the BVH");

    // Bounding sphere of everything finite: lights at infinity deliver power over its disk.
    RTCBounds b;
    rtcGetSceneBounds(scene_, &b);
    Vec3 lo(b.lower_x, b.lower_y, b.lower_z), hi(b.upper_x, b.upper_y, b.upper_z);
    for (const PointLight& p : points_) {
        lo = Vec3(std::min(lo.x, p.position.x), std::min(lo.y, p.position.y), std::min(lo.z, p.position.z));
        hi = Vec3(std::max(hi.x, p.position.x), std::max(hi.y, p.position.y), std::max(hi.z, p.position.z));
    }
    if (lo.x <= hi.x && IsFinite(lo) && IsFinite(hi)) {
        scene_center_ = (lo + hi) * 0.5f;
        scene_radius_ = std::max(1e-3f, 0.5f * Length(hi - lo));
    }

    // Emitters, each weighted by its emitted power Phi = pi * A * L (per side).
    std::vector<double> power;
    triangle_emitter_.assign(num_triangles_, kNoEmitter);
    for (uint32_t t = 0; t < num_triangles_; ++t) {
        const Material& m = materials_[triangle_material_[t]];
        if (IsBlack(m.emission)) continue;
        float area = 0.5f * Length(Cross(Vertex(t, 1) - Vertex(t, 0), Vertex(t, 2) - Vertex(t, 0)));
        if (!(area > 0.f)) continue;  // degenerate: never hit, never sampled
        triangle_emitter_[t] = int32_t(emitters_.size());
        emitters_.push_back({LightKind::kTriangle, t, area, 0.f});
        power.push_back(double(Luminance(m.emission)) * area * kPi * (m.two_sided_emission ? 2.0 : 1.0));
    }
    sphere_emitter_.assign(spheres_.size(), kNoEmitter);
    for (uint32_t s = 0; s < spheres_.size(); ++s) {
        if (IsBlack(spheres_[s].radiance)) continue;
        float area = 4.f * kPi * spheres_[s].radius * spheres_[s].radius;
        sphere_emitter_[s] = int32_t(emitters_.size());
        emitters_.push_back({LightKind::kSphere, s, area, 0.f});
        power.push_back(double(Luminance(spheres_[s].radiance)) * area * kPi);
    }
    for (uint32_t i = 0; i < points_.size(); ++i) {
        if (IsBlack(points_[i].intensity)) continue;
        emitters_.push_back({LightKind::kPoint, i, 0.f, 0.f});
        power.push_back(4.0 * kPi * double(Luminance(points_[i].intensity)));
    }
    const double disk_area = kPi * double(scene_radius_) * scene_radius_;
    for (uint32_t i = 0; i < distants_.size(); ++i) {
        const DistantLight& d = distants_[i];
        if (IsBlack(d.radiance)) continue;
        float sin_half = std::sin(d.half_angle);
        float omc = d.half_angle > 0.f ? ConeOneMinusCos(sin_half * sin_half) : 0.f;
        if (omc > 0.f) environment_lights_.push_back(uint32_t(emitters_.size()));
        emitters_.push_back({LightKind::kDistant, i, 0.f, omc});
        // Irradiance on a facing surface: E = L pi sin^2 (cone), or the stored E (delta).
        double irradiance = double(Luminance(d.radiance)) * (omc > 0.f ? kPi * sin_half * sin_half : 1.0);
        power.push_back(irradiance * disk_area);
    }
    if (!IsBlack(dome_radiance_) && (!DomeTextured() || !dome_distribution_.empty())) {
        double mean = 1.0;  // solid-angle mean of the texture's luminance
        if (DomeTextured()) {
            double sum = 0.0, weight = 0.0;
            for (uint32_t y = 0; y < dome_h_; ++y) {
                double sin_theta = std::sin(kPi * (y + 0.5) / dome_h_);
                for (uint32_t x = 0; x < dome_w_; ++x) {
                    const float* t = &dome_rgb_[3 * (size_t(y) * dome_w_ + x)];
                    sum += Luminance(Color(t[0], t[1], t[2])) * sin_theta;
                    weight += sin_theta;
                }
            }
            mean = sum / weight;
        }
        environment_lights_.push_back(uint32_t(emitters_.size()));
        emitters_.push_back({LightKind::kDome, 0, 0.f, 0.f});
        power.push_back(4.0 * kPi * disk_area * double(Luminance(dome_radiance_)) * mean);
    }
    light_sampler_ = LightSampler(power);
}

Scene::~Scene() {
    if (scene_) rtcReleaseScene(scene_);
}

Vec3 Scene::Vertex(uint32_t tri, int corner) const {
    const float* p = positions_ + 3 * size_t(indices_[3 * size_t(tri) + corner]);
    return {p[0], p[1], p[2]};
}

bool Scene::IsCutoutHit(const SurfaceHit& hit) const {
    return hit.geom_id == kTriangleGeometry && material_is_cutout_[triangle_material_[hit.prim_id]];
}

bool Scene::Intersect(const Ray& ray, SurfaceHit* hit, float t_min, float t_max) const {
    if (!has_cutouts_) return IntersectClosest(ray, t_min, t_max, hit);
    // Step through cutout surfaces. Each step restarts just past the previous hit, so a
    // ray crosses at most as many cutout layers as lie along it.
    float t_near = t_min;
    for (int layer = 0; layer < 1024; ++layer) {
        if (!IntersectClosest(ray, t_near, t_max, hit)) return false;
        if (!IsCutoutHit(*hit)) return true;
        t_near = std::nextafter(hit->t, std::numeric_limits<float>::infinity()) * (1.f + 1e-6f);
    }
    return false;
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
    rh.ray.time = 0.f;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    ++tls_ray_counters.closest;
    rtcIntersect1(scene_, &context, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
    hit->t = rh.ray.tfar;
    hit->geom_id = rh.hit.geomID;
    hit->prim_id = rh.hit.primID;
    if (rh.hit.geomID == kTriangleGeometry) {
        // Recompute the hit point from barycentrics: smaller error than o + t d far away.
        Vec3 p0 = Vertex(rh.hit.primID, 0), p1 = Vertex(rh.hit.primID, 1), p2 = Vertex(rh.hit.primID, 2);
        float u = rh.hit.u, v = rh.hit.v;
        hit->p = p0 * (1.f - u - v) + p1 * u + p2 * v;
        hit->ng = Normalize(Cross(p1 - p0, p2 - p0));
        hit->ns = hit->ng;
        if (!shading_normals_.empty()) {
            const float* n = &shading_normals_[9 * size_t(rh.hit.primID)];
            Vec3 ns = Vec3(n[0], n[1], n[2]) * (1.f - u - v) + Vec3(n[3], n[4], n[5]) * u + Vec3(n[6], n[7], n[8]) * v;
            float len = Length(ns);
            // Degenerate or non-finite authored normals fall back to the facet's.
            if (len > 1e-6f && std::isfinite(len)) hit->ns = Dot(ns, hit->ng) >= 0.f ? ns / len : -ns / len;
        }
    } else {
        const SphereLight& s = spheres_[rh.hit.primID];
        Vec3 p = ray.o + ray.d * rh.ray.tfar;
        hit->ng = Normalize(p - s.center);
        hit->ns = hit->ng;
        hit->p = s.center + hit->ng * s.radius;
    }
    return true;
}

bool Scene::Occluded(Vec3 origin, Vec3 dir, float t_far) const {
    if (has_cutouts_) {
        SurfaceHit hit;
        return Intersect({origin, dir}, &hit) && hit.t < t_far;
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
    ray.time = 0.f;
    ray.mask = 0xFFFFFFFFu;
    ray.id = 0;
    ray.flags = 0;
    ++tls_ray_counters.shadow;
    rtcOccluded1(scene_, &context, &ray);
    return ray.tfar < 0.f;  // Embree sets tfar = -inf on a hit
}

const Material& Scene::MaterialAt(const SurfaceHit& hit) const {
    static const Material kLightSurface{Color(0.f), Color(0.f), false, std::nullopt};
    return hit.geom_id == kTriangleGeometry ? materials_[triangle_material_[hit.prim_id]] : kLightSurface;
}

BSDF Scene::BSDFAt(const SurfaceHit& hit, TransportMode mode) const {
    if (hit.geom_id != kTriangleGeometry) return BSDF();
    const Material& m = materials_[triangle_material_[hit.prim_id]];
    if (m.preview) return MakePreviewSurfaceBSDF(*m.preview, mode);
    return BSDF(DiffuseBSDF(m.albedo));
}

int32_t Scene::EmitterAt(const SurfaceHit& hit) const {
    return hit.geom_id == kTriangleGeometry ? triangle_emitter_[hit.prim_id] : sphere_emitter_[hit.prim_id];
}

Color Scene::Emitted(int32_t emitter, const SurfaceHit& hit, Vec3 wo) const {
    if (emitter < 0) return Color(0.f);
    const Emitter& e = emitters_[emitter];
    if (e.kind == LightKind::kSphere) return spheres_[e.index].radiance;
    const Material& m = materials_[triangle_material_[e.index]];
    return (m.two_sided_emission || Dot(hit.ng, wo) > 0.f) ? m.emission : Color(0.f);
}

bool Scene::SampleEmitter(uint32_t emitter, Vec3 ref, Vec2 u, LightSample* out) const {
    const Emitter& e = emitters_[emitter];
    out->is_delta = false;
    switch (e.kind) {
        case LightKind::kPoint: {
            const PointLight& p = points_[e.index];
            Vec3 to_light = p.position - ref;
            float d2 = LengthSquared(to_light);
            if (!(d2 > 0.f)) return false;
            out->distance = std::sqrt(d2);
            out->wi = to_light / out->distance;
            out->radiance = p.intensity / d2;  // inverse-square law
            out->pdf = 1.f;
            out->is_delta = true;
            out->n = Vec3(0.f);
            return true;
        }
        case LightKind::kDistant: {
            const DistantLight& d = distants_[e.index];
            out->distance = std::numeric_limits<float>::infinity();
            out->radiance = d.radiance;
            out->n = Vec3(0.f);
            if (e.one_minus_cos == 0.f) {  // delta: the stored value is the irradiance
                out->wi = -d.direction;
                out->pdf = 1.f;
                out->is_delta = true;
                return true;
            }
            out->wi = Normalize(Frame::FromZ(-d.direction).FromLocal(SampleUniformCone(u, e.one_minus_cos)));
            out->pdf = 1.f / (2.f * kPi * e.one_minus_cos);
            return true;
        }
        case LightKind::kDome: {
            out->wi = SampleDome(u, &out->pdf, &out->radiance);
            out->distance = std::numeric_limits<float>::infinity();
            out->n = Vec3(0.f);
            return out->pdf > 0.f;
        }
        case LightKind::kSphere:
        case LightKind::kTriangle:
            break;
    }
    if (e.kind == LightKind::kSphere) {
        // Uniform in the cone the sphere subtends (pbrt-v4 4.2 / 12.2.2): no samples wasted
        // on the hidden back side. From inside the sphere there is no light sampling.
        const SphereLight& s = spheres_[e.index];
        Vec3 to_center = s.center - ref;
        float d2 = LengthSquared(to_center);
        float r2 = s.radius * s.radius;
        if (d2 <= r2) return false;
        float d = std::sqrt(d2);
        float one_minus_cos = ConeOneMinusCos(r2 / d2);
        Vec3 local = SampleUniformCone(u, one_minus_cos);
        Vec3 wi = Normalize(Frame::FromZ(to_center / d).FromLocal(local));
        // Nearest intersection of ref + t wi with the sphere.
        float b = Dot(to_center, wi);
        float disc = std::max(0.f, r2 - (d2 - b * b));
        out->distance = b - std::sqrt(disc);
        out->wi = wi;
        out->radiance = s.radiance;
        out->pdf = 1.f / (2.f * kPi * one_minus_cos);
        out->n = Normalize(ref + wi * out->distance - s.center);
        return out->distance > 0.f;
    }
    Vec3 b = SampleUniformTriangle(u);
    Vec3 p0 = Vertex(e.index, 0), p1 = Vertex(e.index, 1), p2 = Vertex(e.index, 2);
    Vec3 p = p0 * b.x + p1 * b.y + p2 * b.z;
    Vec3 ng = Normalize(Cross(p1 - p0, p2 - p0));
    Vec3 to_light = p - ref;
    float d2 = LengthSquared(to_light);
    if (!(d2 > 0.f)) return false;
    float d = std::sqrt(d2);
    Vec3 wi = to_light / d;
    float cos_light = Dot(ng, -wi);
    const Material& m = materials_[triangle_material_[e.index]];
    if (!m.two_sided_emission && cos_light <= 0.f) return false;
    cos_light = std::abs(cos_light);
    if (cos_light < 1e-7f) return false;
    out->wi = wi;
    out->distance = d;
    out->radiance = m.emission;
    out->pdf = d2 / (cos_light * e.area);  // area measure 1/A converted to solid angle
    out->n = ng;
    return true;
}

bool Scene::SampleEmission(uint32_t emitter, Vec2 u_pos, Vec2 u_dir, float u_side, EmissionSample* out) const {
    const Emitter& e = emitters_[emitter];
    out->on_surface = false;
    switch (e.kind) {
        case LightKind::kTriangle: {
            const Material& m = materials_[triangle_material_[e.index]];
            Vec3 p0 = Vertex(e.index, 0), p1 = Vertex(e.index, 1), p2 = Vertex(e.index, 2);
            Vec3 b = SampleUniformTriangle(u_pos);
            Vec3 n = Normalize(Cross(p1 - p0, p2 - p0));
            float sides = 1.f;
            if (m.two_sided_emission) {
                sides = 2.f;
                if (u_side < 0.5f) n = -n;
            }
            out->p = p0 * b.x + p1 * b.y + p2 * b.z;
            out->n = n;
            out->wo = Normalize(Frame::FromZ(n).FromLocal(SampleCosineHemisphere(u_dir)));
            // Le cos / ((1/A) (cos/pi) (1/sides)) = Le pi A sides
            out->beta = m.emission * (kPi * e.area * sides);
            out->on_surface = true;
            out->Le = m.emission;
            out->pdf_pos = 1.f / e.area;
            out->pdf_dir = std::abs(Dot(out->wo, n)) * kInvPi / sides;
            out->infinite = out->delta_light = false;
            return true;
        }
        case LightKind::kSphere: {
            const SphereLight& s = spheres_[e.index];
            float z = 1.f - 2.f * u_pos.x, r = std::sqrt(std::max(0.f, 1.f - z * z)), phi = 2.f * kPi * u_pos.y;
            Vec3 n(r * std::cos(phi), r * std::sin(phi), z);
            out->p = s.center + n * s.radius;
            out->n = n;
            out->wo = Normalize(Frame::FromZ(n).FromLocal(SampleCosineHemisphere(u_dir)));
            out->beta = s.radiance * (kPi * e.area);
            out->on_surface = true;
            out->Le = s.radiance;
            out->pdf_pos = 1.f / e.area;
            out->pdf_dir = std::abs(Dot(out->wo, n)) * kInvPi;
            out->infinite = out->delta_light = false;
            return true;
        }
        case LightKind::kPoint: {
            const PointLight& pl = points_[e.index];
            float z = 1.f - 2.f * u_dir.x, r = std::sqrt(std::max(0.f, 1.f - z * z)), phi = 2.f * kPi * u_dir.y;
            out->p = pl.position;
            out->wo = Vec3(r * std::cos(phi), r * std::sin(phi), z);
            out->beta = pl.intensity * (4.f * kPi);  // I / (1 / 4 pi)
            out->Le = pl.intensity;
            out->pdf_pos = 1.f;
            out->pdf_dir = 1.f / (4.f * kPi);
            out->infinite = false;
            out->delta_light = true;
            return true;
        }
        case LightKind::kDistant:
        case LightKind::kDome: {
            float pdf_dir = 1.f;
            Color L;
            if (e.kind == LightKind::kDome) {
                out->wo = -SampleDome(u_dir, &pdf_dir, &L);  // light travels away from the dome
                if (!(pdf_dir > 0.f)) return false;
            } else {
                const DistantLight& d = distants_[e.index];
                L = d.radiance;
                if (e.one_minus_cos > 0.f) {
                    out->wo = Normalize(Frame::FromZ(d.direction).FromLocal(SampleUniformCone(u_dir, e.one_minus_cos)));
                    pdf_dir = 1.f / (2.f * kPi * e.one_minus_cos);
                } else {
                    out->wo = d.direction;  // delta: L holds the irradiance
                }
            }
            // A point on the disk of the bounding sphere facing wo, upstream of the scene.
            Vec2 disk = SampleUniformDiskConcentric(u_pos);
            Frame f = Frame::FromZ(out->wo);
            out->p = scene_center_ + (f.s * disk.x + f.t * disk.y - out->wo) * scene_radius_;
            float pdf_pos = 1.f / (kPi * scene_radius_ * scene_radius_);
            out->beta = L / (pdf_pos * pdf_dir);
            out->Le = L;
            out->pdf_pos = pdf_pos;
            out->pdf_dir = pdf_dir;
            out->infinite = true;
            out->delta_light = e.kind == LightKind::kDistant && e.one_minus_cos == 0.f;
            return true;
        }
    }
    return false;
}

float Scene::EmissionPdfDirection(uint32_t emitter, Vec3 n, Vec3 w) const {
    const Emitter& e = emitters_[emitter];
    switch (e.kind) {
        case LightKind::kPoint:
            return 1.f / (4.f * kPi);
        case LightKind::kSphere:
            return std::max(0.f, Dot(n, w)) * kInvPi;
        case LightKind::kTriangle: {
            const Material& m = materials_[triangle_material_[e.index]];
            if (m.two_sided_emission) return std::abs(Dot(n, w)) * kInvPi * 0.5f;
            return std::max(0.f, Dot(n, w)) * kInvPi;
        }
        case LightKind::kDistant:
            return e.one_minus_cos > 0.f ? 1.f / (2.f * kPi * e.one_minus_cos) : 0.f;
        case LightKind::kDome: {
            float pdf;
            DomeRadiance(-w, &pdf);
            return pdf;
        }
    }
    return 0.f;
}

float Scene::EmissionPdfPosition(uint32_t emitter) const {
    const Emitter& e = emitters_[emitter];
    switch (e.kind) {
        case LightKind::kPoint:
            return 1.f;
        case LightKind::kSphere:
        case LightKind::kTriangle:
            return 1.f / e.area;
        case LightKind::kDistant:
        case LightKind::kDome:
            return 1.f / (kPi * scene_radius_ * scene_radius_);
    }
    return 0.f;
}

float Scene::InfiniteLightDensity(Vec3 w) const {
    float pdf = 0.f;
    for (uint32_t i : environment_lights_) {
        float p = 0.f;
        EnvironmentRadiance(emitters_[i], w, &p);
        pdf += light_sampler_.Pmf(i) * p;
    }
    return pdf;
}

bool Scene::IsInfiniteLight(uint32_t emitter) const {
    LightKind k = emitters_[emitter].kind;
    return k == LightKind::kDistant || k == LightKind::kDome;
}

bool Scene::IsDeltaLight(uint32_t emitter) const {
    const Emitter& e = emitters_[emitter];
    return e.kind == LightKind::kPoint || (e.kind == LightKind::kDistant && e.one_minus_cos == 0.f);
}

Color Scene::DomeRadiance(Vec3 w, float* pdf) const {
    if (!DomeTextured()) {
        *pdf = 1.f / (4.f * kPi);
        return dome_radiance_;
    }
    const float* m = dome_m_;
    Vec3 l(m[0] * w.x + m[1] * w.y + m[2] * w.z, m[3] * w.x + m[4] * w.y + m[5] * w.z,
           m[6] * w.x + m[7] * w.y + m[8] * w.z);
    // OpenEXR lat-long: longitude +pi..-pi across, latitude +pi/2..-pi/2 down; (lat 0,
    // lon 0) is +z and (0, pi/2) is +x.
    const float lat = std::asin(std::clamp(l.y, -1.f, 1.f)), lon = std::atan2(l.x, l.z);
    const Vec2 uv{0.5f - lon * kInv2Pi, 0.5f - lat * kInvPi};
    const float cos_lat = std::cos(lat);
    *pdf = cos_lat > 0.f ? dome_distribution_.Pdf(uv) / (2.f * kPi * kPi * cos_lat) : 0.f;
    uint32_t x = std::min(dome_w_ - 1, uint32_t(std::max(0.f, uv.x) * float(dome_w_)));
    uint32_t y = std::min(dome_h_ - 1, uint32_t(std::max(0.f, uv.y) * float(dome_h_)));
    const float* t = &dome_rgb_[3 * (size_t(y) * dome_w_ + x)];
    return dome_radiance_ * Color(t[0], t[1], t[2]);
}

Vec3 Scene::SampleDome(Vec2 u, float* pdf, Color* L) const {
    if (!DomeTextured()) {
        float z = 1.f - 2.f * u.x, r = std::sqrt(std::max(0.f, 1.f - z * z)), phi = 2.f * kPi * u.y;
        *pdf = 1.f / (4.f * kPi);
        *L = dome_radiance_;
        return Vec3(r * std::cos(phi), r * std::sin(phi), z);
    }
    float pdf_uv;
    const Vec2 uv = dome_distribution_.Sample(u, &pdf_uv);
    const float lon = kPi * (1.f - 2.f * uv.x), lat = kPi * (0.5f - uv.y);
    const float cos_lat = std::cos(lat);
    const Vec3 l(cos_lat * std::sin(lon), std::sin(lat), cos_lat * std::cos(lon));
    const float* m = dome_m_;  // world = M^T l (M is a rotation)
    const Vec3 w = Normalize(Vec3(m[0] * l.x + m[3] * l.y + m[6] * l.z, m[1] * l.x + m[4] * l.y + m[7] * l.z,
                                  m[2] * l.x + m[5] * l.y + m[8] * l.z));
    *pdf = cos_lat > 0.f ? pdf_uv / (2.f * kPi * kPi * cos_lat) : 0.f;
    // The radiance of the texel the direction falls in (as DomeRadiance looks it up).
    float unused;
    *L = DomeRadiance(w, &unused);
    return w;
}

Color Scene::EnvironmentRadiance(const Emitter& e, Vec3 dir, float* pdf) const {
    if (e.kind == LightKind::kDome) return DomeRadiance(dir, pdf);
    const DistantLight& d = distants_[e.index];
    // Inside the cone: 1 - cos(angle to the axis) <= 1 - cos(half angle).
    if (1.f - Dot(dir, -d.direction) <= e.one_minus_cos) {
        *pdf = 1.f / (2.f * kPi * e.one_minus_cos);
        return d.radiance;
    }
    *pdf = 0.f;
    return Color(0.f);
}

float Scene::EmitterPdf(uint32_t emitter, Vec3 ref, const SurfaceHit& hit) const {
    const Emitter& e = emitters_[emitter];
    if (e.kind == LightKind::kSphere) {
        const SphereLight& s = spheres_[e.index];
        float d2 = LengthSquared(s.center - ref);
        float r2 = s.radius * s.radius;
        if (d2 <= r2) return 0.f;
        return 1.f / (2.f * kPi * ConeOneMinusCos(r2 / d2));
    }
    Vec3 to_light = hit.p - ref;
    float d2 = LengthSquared(to_light);
    float cos_light = std::abs(Dot(hit.ng, to_light)) / std::sqrt(d2);
    if (cos_light < 1e-7f) return 0.f;
    return d2 / (cos_light * e.area);
}

}  // namespace tessera
