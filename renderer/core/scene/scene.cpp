#include "scene.h"

#include <algorithm>

#include <atomic>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>

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

void CheckDevice(RTCDevice device, const char* what) {
    RTCError err = rtcGetDeviceError(device);
    if (err != RTC_ERROR_NONE)
        throw std::runtime_error(std::string("Embree error ") + std::to_string(int(err)) + " in " + what);
}

bool IsNonNegativeFinite(Color c) {
    return IsFinite(c) && c.x >= 0.f && c.y >= 0.f && c.z >= 0.f;
}

}  // namespace

namespace {
std::atomic<int64_t> g_embree_bytes{0};
// Embree reports every allocation and release; returning true lets it proceed.
bool MonitorEmbreeMemory(void*, ssize_t bytes, bool) {
    g_embree_bytes.fetch_add(int64_t(bytes), std::memory_order_relaxed);
    return true;
}
}  // namespace

RTCDevice EmbreeDevice() {
    static RTCDevice device = [] {
        RTCDevice d = rtcNewDevice("verbose=0");
        if (!d) throw std::runtime_error("cannot create the Embree device");
        rtcSetDeviceMemoryMonitorFunction(d, MonitorEmbreeMemory, nullptr);
        return d;
    }();
    return device;
}

int64_t EmbreeMemoryBytes() {
    EmbreeDevice();
    return g_embree_bytes.load(std::memory_order_relaxed);
}

Scene::Scene(const SceneDesc& desc)
    : materials_(desc.materials),
      spheres_(desc.sphere_lights),
      points_(desc.point_lights),
      distants_(desc.distant_lights) {
    textures_ = TextureSet(desc.images, desc.textures);
    for (size_t m = 0; m < materials_.size(); ++m) {
        if (!IsNonNegativeFinite(materials_[m].albedo) || !IsNonNegativeFinite(materials_[m].emission) ||
            MaxComponent(materials_[m].albedo) > 1.f)
            throw std::invalid_argument("material " + std::to_string(m) +
                                        ": albedo must be in [0, 1] and emission finite and >= 0");
        for (int slot = 0; slot < kNumTextureSlots; ++slot) {
            const int32_t t = materials_[m].textures[slot];
            if (t < -1 || t >= int64_t(textures_.size()))
                throw std::invalid_argument("material " + std::to_string(m) + " refers to texture " +
                                            std::to_string(t) + " of " + std::to_string(textures_.size()));
            // Textures drive UsdPreviewSurface inputs; a plain Lambertian has none to drive.
            if (t >= 0 && !materials_[m].preview) materials_[m].textures[slot] = -1;
        }
        material_has_textures_.push_back(materials_[m].textures != NoTextures());
        // Cutout by the material's own opacity, or possibly by its opacity texture (then
        // decided per hit in IsCutoutHit).
        const auto& pv = materials_[m].preview;
        const bool textured_opacity = materials_[m].textures[kSlotOpacity] >= 0;
        material_is_cutout_.push_back(
            pv && (IsPresenceMode(*pv) ? textured_opacity || pv->opacity < 1.f
                                       : textured_opacity ? pv->opacity_threshold > 0.f
                                                          : IsCutout(*pv, pv->opacity)));
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
    if (!IsNonNegativeFinite(desc.dome_radiance)) throw std::invalid_argument("dome radiance must be finite and >= 0");
    dome_ = DomeLight(desc.dome_radiance, desc.dome_width, desc.dome_height, desc.dome_rgb, desc.dome_world_to_light);

    // From here on Embree objects exist: a throw must release them, since a constructor
    // that throws never runs its destructor.
    try {
        BuildGeometryAndLights(desc);
    } catch (...) {
        ReleaseEmbree();
        throw;
    }
}

// The BVHs (the world's, one per prototype, the instances), then the light table.
void Scene::BuildGeometryAndLights(const SceneDesc& desc) {
    RTCDevice device = EmbreeDevice();
    scene_ = rtcNewScene(device);
    // Watertight triangle test: a closed mesh must not leak light through its edges.
    rtcSetSceneFlags(scene_, RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(scene_, RTC_BUILD_QUALITY_HIGH);

    // The world mesh is geometry 0 of the top-level BVH (present even when empty, so the
    // geometry ids stay fixed); each prototype gets its own BVH, instanced below.
    if (desc.positions.size() % 3 != 0) throw std::invalid_argument("positions must hold 3 floats per vertex");
    if (desc.indices.size() % 3 != 0) throw std::invalid_argument("indices must hold 3 per triangle");
    meshes_.resize(1 + desc.prototypes.size());
    BuildMesh(&meshes_[0], desc.positions.data(), desc.positions.size() / 3, desc.indices.data(),
              desc.indices.size() / 3, desc.triangle_material, desc.shading_normals, desc.uvs, scene_,
              kTriangleGeometry, "");
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
        rtcAttachGeometryByID(scene_, geom, kSphereGeometry);
        rtcReleaseGeometry(geom);
    }
    for (size_t k = 0; k < desc.prototypes.size(); ++k) {
        const MeshDesc& pd = desc.prototypes[k];
        const std::string what = "prototype " + std::to_string(k) + ": ";
        if (pd.positions.size() % 3 != 0 || pd.indices.size() % 3 != 0)
            throw std::invalid_argument(what + "positions and indices must hold 3 values per vertex / triangle");
        Mesh& mesh = meshes_[1 + k];
        mesh.scene = rtcNewScene(device);
        rtcSetSceneFlags(mesh.scene, RTC_SCENE_FLAG_ROBUST);
        rtcSetSceneBuildQuality(mesh.scene, RTC_BUILD_QUALITY_HIGH);
        BuildMesh(&mesh, pd.positions.data(), pd.positions.size() / 3, pd.indices.data(), pd.indices.size() / 3,
                  pd.triangle_material, pd.shading_normals, pd.uvs, mesh.scene, 0, what);
        rtcCommitScene(mesh.scene);
        CheckDevice(device, "building a prototype BVH");
    }
    const size_t num_instances = desc.instance_prototype.size();
    if (desc.instance_transforms.size() != 12 * num_instances)
        throw std::invalid_argument("instance_transforms must hold one 3x4 matrix per instance");
    instances_.resize(num_instances);
    num_triangles_ = meshes_[0].num_triangles;
    for (size_t i = 0; i < num_instances; ++i) {
        const uint32_t proto = desc.instance_prototype[i];
        if (proto >= desc.prototypes.size())
            throw std::invalid_argument("instance " + std::to_string(i) + " refers to prototype " +
                                        std::to_string(proto) + " of " + std::to_string(desc.prototypes.size()));
        Instance& inst = instances_[i];
        inst.mesh = 1 + proto;
        std::copy(desc.instance_transforms.begin() + 12 * i, desc.instance_transforms.begin() + 12 * (i + 1), inst.m);
        const float* m = inst.m;
        bool finite = true;
        for (int j = 0; j < 12; ++j) finite = finite && std::isfinite(m[j]);
        // Inverse transpose of the 3x3 part = cofactor matrix / determinant.
        const double c00 = double(m[5]) * m[10] - double(m[6]) * m[9], c01 = double(m[6]) * m[8] - double(m[4]) * m[10],
                     c02 = double(m[4]) * m[9] - double(m[5]) * m[8];
        const double c10 = double(m[2]) * m[9] - double(m[1]) * m[10], c11 = double(m[0]) * m[10] - double(m[2]) * m[8],
                     c12 = double(m[1]) * m[8] - double(m[0]) * m[9];
        const double c20 = double(m[1]) * m[6] - double(m[2]) * m[5], c21 = double(m[2]) * m[4] - double(m[0]) * m[6],
                     c22 = double(m[0]) * m[5] - double(m[1]) * m[4];
        const double det = double(m[0]) * c00 + double(m[1]) * c01 + double(m[2]) * c02;
        if (!finite || !(std::abs(det) > 1e-30) || !std::isfinite(det))
            throw std::invalid_argument("instance " + std::to_string(i) +
                                        " has a non-finite or singular transform");
        const double cof[9] = {c00, c01, c02, c10, c11, c12, c20, c21, c22};
        for (int j = 0; j < 9; ++j) inst.n[j] = float(cof[j] / det);
        inst.orientation = det < 0.0 ? -1.f : 1.f;
        RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_INSTANCE);
        rtcSetGeometryInstancedScene(geom, meshes_[inst.mesh].scene);
        rtcSetGeometryTransform(geom, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, inst.m);
        rtcCommitGeometry(geom);
        rtcAttachGeometryByID(scene_, geom, kFirstInstanceGeometry + uint32_t(i));
        rtcReleaseGeometry(geom);
        CheckDevice(device, "creating instances");
        num_triangles_ += meshes_[inst.mesh].num_triangles;
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
    // Textured emission: light selection weighs the triangle by the texture's mean (the
    // image average, not the average over the triangle's st footprint: a cheap estimate
    // that only affects variance, never the expectation).
    std::vector<Color> emission_estimate(materials_.size());
    for (size_t m = 0; m < materials_.size(); ++m) {
        const int32_t t = materials_[m].textures[kSlotEmissiveColor];
        emission_estimate[m] = t >= 0 ? textures_.MeanColor(uint32_t(t)) : materials_[m].emission;
    }
    auto add_triangle_emitter = [&](uint32_t mesh, uint32_t prim, uint32_t instance) {
        Vec3 p[3];
        TriangleVertices(mesh, prim, instance, p);
        // A prototype triangle that is not degenerate locally stays an emitter in every
        // instance (the emitter base + local index mapping needs all of them); the clamp
        // only guards a transform that shrinks it below float range.
        const float area = std::max(1e-30f, 0.5f * Length(Cross(p[1] - p[0], p[2] - p[0])));
        const uint32_t mi = meshes_[mesh].material[prim];
        emitters_.push_back({LightKind::kTriangle, prim, area, 0.f, mesh, instance});
        power.push_back(double(Luminance(emission_estimate[mi])) * area * kPi *
                        (materials_[mi].two_sided_emission ? 2.0 : 1.0));
    };
    for (size_t k = 0; k < meshes_.size(); ++k) {
        Mesh& mesh = meshes_[k];
        mesh.emitter.assign(mesh.num_triangles, kNoEmitter);
        for (uint32_t t = 0; t < mesh.num_triangles; ++t) {
            if (IsBlack(emission_estimate[mesh.material[t]])) continue;
            Vec3 p[3];
            TriangleVertices(uint32_t(k), t, kNoInstance, p);
            if (!(Length(Cross(p[1] - p[0], p[2] - p[0])) > 0.f)) continue;  // degenerate: never hit, never sampled
            if (k == 0) {
                mesh.emitter[t] = int32_t(emitters_.size());
                add_triangle_emitter(0, t, kNoInstance);
            } else {
                mesh.emitter[t] = int32_t(mesh.num_emissive++);
            }
        }
    }
    // Every instance of a prototype with emissive triangles is a light of its own.
    for (uint32_t i = 0; i < instances_.size(); ++i) {
        const Mesh& mesh = meshes_[instances_[i].mesh];
        if (mesh.num_emissive == 0) continue;
        instances_[i].emitter_base = int32_t(emitters_.size());
        for (uint32_t t = 0; t < mesh.num_triangles; ++t)
            if (mesh.emitter[t] >= 0) add_triangle_emitter(instances_[i].mesh, t, i);
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
    if (dome_.active()) {
        const double mean = dome_.MeanLuminance();  // solid-angle mean of the texture's luminance
        environment_lights_.push_back(uint32_t(emitters_.size()));
        emitters_.push_back({LightKind::kDome, 0, 0.f, 0.f});
        power.push_back(4.0 * kPi * disk_area * double(Luminance(dome_.radiance())) * mean);
    }
    light_sampler_ = LightSampler(power);

    // The splat film's unit (splat_film.h): the power of two nearest the radiance the lights
    // can give a diffuse surface, Phi / (pi^2 R^2), so that the fixed point keeps 2^-24 of
    // it as resolution and 2^39 as headroom whatever the scene's emission scale (1e-30 and
    // 1e30 alike). Every tile of a scene uses the same unit, so sums stay exact.
    double total = 0.0;
    for (double p : power) total += p;
    const double typical = total / (kPi * kPi * double(scene_radius_) * double(scene_radius_));
    if (typical > 0.0 && std::isfinite(typical))
        splat_exponent_ = std::clamp(int(std::lround(std::log2(typical))), -120, 120);
}

Scene::~Scene() { ReleaseEmbree(); }

void Scene::ReleaseEmbree() noexcept {
    if (scene_) rtcReleaseScene(scene_);
    scene_ = nullptr;
    for (Mesh& m : meshes_) {
        if (m.scene) rtcReleaseScene(m.scene);
        m.scene = nullptr;
    }
}

size_t Scene::num_stored_triangles() const {
    size_t n = 0;
    for (const Mesh& m : meshes_) n += m.num_triangles;
    return n;
}

void Scene::BuildMesh(Mesh* mesh, const float* positions, size_t num_vertices, const uint32_t* indices,
                      size_t num_triangles, const std::vector<uint32_t>& material, const std::vector<float>& normals,
                      const std::vector<float>& uvs, RTCScene target, uint32_t geom_id, const std::string& what) {
    if (material.size() != num_triangles)
        throw std::invalid_argument(what + "triangle_material must have one entry per triangle");
    if (num_vertices > 0xFFFFFFFFull) throw std::invalid_argument(what + "too many vertices");
    if (!normals.empty() && normals.size() != 9 * num_triangles)
        throw std::invalid_argument(what + "shading_normals must hold 3 normals per triangle");
    if (!uvs.empty() && uvs.size() != 6 * num_triangles)
        throw std::invalid_argument(what + "uvs must hold 3 st pairs per triangle");
    for (size_t i = 0; i < 3 * num_vertices; ++i)
        if (!std::isfinite(positions[i]))
            throw std::invalid_argument(what + "vertex " + std::to_string(i / 3) + " has a non-finite coordinate");
    for (size_t i = 0; i < 3 * num_triangles; ++i)
        if (indices[i] >= num_vertices)
            throw std::invalid_argument(what + "triangle " + std::to_string(i / 3) + " indexes vertex " +
                                        std::to_string(indices[i]) + " of " + std::to_string(num_vertices));
    for (size_t t = 0; t < num_triangles; ++t)
        if (material[t] >= materials_.size())
            throw std::invalid_argument(what + "triangle " + std::to_string(t) + " has material " +
                                        std::to_string(material[t]) + " of " + std::to_string(materials_.size()));
    // The core would look textures up at NaN st; the translation replaces them, so this
    // is a caller's bug, reported with the triangle.
    for (size_t i = 0; i < uvs.size(); ++i)
        if (!std::isfinite(uvs[i]))
            throw std::invalid_argument(what + "triangle " + std::to_string(i / 6) + " has a non-finite st");
    mesh->material = material;
    mesh->normals = normals;
    mesh->uvs = uvs;
    mesh->num_triangles = num_triangles;
    RTCDevice device = EmbreeDevice();
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
    // Embree may read 16 bytes from the last vertex, hence one vertex of padding.
    auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                           3 * sizeof(float), num_vertices + 1));
    auto* ib = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                              3 * sizeof(uint32_t), num_triangles));
    CheckDevice(device, "allocating triangle buffers");
    std::copy(positions, positions + 3 * num_vertices, vb);
    vb[3 * num_vertices] = vb[3 * num_vertices + 1] = vb[3 * num_vertices + 2] = 0.f;
    std::copy(indices, indices + 3 * num_triangles, ib);
    mesh->positions = vb;
    mesh->indices = ib;
    rtcCommitGeometry(geom);
    rtcAttachGeometryByID(target, geom, geom_id);
    rtcReleaseGeometry(geom);
    CheckDevice(device, "attaching triangles");
}

namespace {

inline Vec3 LocalVertex(const float* positions, const uint32_t* indices, uint32_t tri, int corner) {
    const float* p = positions + 3 * size_t(indices[3 * size_t(tri) + corner]);
    return {p[0], p[1], p[2]};
}
inline Vec3 TransformPoint(const float* m, Vec3 p) {
    return {m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3], m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
            m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]};
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
inline Vec3 TransformVector(const float* m, Vec3 v) {  // m: row-major 3x4
    return {m[0] * v.x + m[1] * v.y + m[2] * v.z, m[4] * v.x + m[5] * v.y + m[6] * v.z,
            m[8] * v.x + m[9] * v.y + m[10] * v.z};
}
inline Vec3 TransformNormal(const float* n, Vec3 v) {  // n: row-major 3x3
    return {n[0] * v.x + n[1] * v.y + n[2] * v.z, n[3] * v.x + n[4] * v.y + n[5] * v.z,
            n[6] * v.x + n[7] * v.y + n[8] * v.z};
}

}  // namespace

float Scene::TriangleVertices(uint32_t mesh, uint32_t prim, uint32_t instance, Vec3 p[3]) const {
    const Mesh& m = meshes_[mesh];
    for (int c = 0; c < 3; ++c) {
        p[c] = LocalVertex(m.positions, m.indices, prim, c);
        if (instance != kNoInstance) p[c] = TransformPoint(instances_[instance].m, p[c]);
    }
    // A mirroring instance transform reverses the winding of the transformed corners; the
    // flattened copy reverses its corner order instead, so the side a triangle faces is
    // the same either way: Cross(p1 - p0, p2 - p0) times this sign.
    return instance != kNoInstance ? instances_[instance].orientation : 1.f;
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
    if (t < 0) return m.emission;
    const Color c = textures_.EvaluateColor(uint32_t(t), TriangleST(meshes_[mesh], prim, b1, b2));
    return {std::max(0.f, c.x), std::max(0.f, c.y), std::max(0.f, c.z)};
}

void Scene::ApplyTextures(const Material& m, Vec2 st, MaterialParams* p) const {
    auto color = [&](TextureSlot slot, Color* out) {
        if (m.textures[slot] >= 0) *out = textures_.EvaluateColor(uint32_t(m.textures[slot]), st);
    };
    auto scalar = [&](TextureSlot slot, float* out) {
        if (m.textures[slot] >= 0) *out = textures_.EvaluateFloat(uint32_t(m.textures[slot]), st);
    };
    // Out-of-range values (a texture scaled past 1, say) are sanitised by
    // MakePreviewSurfaceBSDF like constant inputs are.
    color(kSlotDiffuseColor, &p->diffuse_color);
    color(kSlotEmissiveColor, &p->emissive_color);
    color(kSlotSpecularColor, &p->specular_color);
    scalar(kSlotMetallic, &p->metallic);
    scalar(kSlotRoughness, &p->roughness);
    scalar(kSlotClearcoat, &p->clearcoat);
    scalar(kSlotClearcoatRoughness, &p->clearcoat_roughness);
    scalar(kSlotOpacity, &p->opacity);
    scalar(kSlotIor, &p->ior);
}

void Scene::ApplyNormalMap(SurfaceHit* hit) const {
    if (hit->geom_id != kTriangleGeometry) return;
    const Material& mat = MaterialOf(hit->mesh, hit->prim_id);
    const int32_t tex = mat.textures[kSlotNormal];
    const Mesh& mesh = meshes_[hit->mesh];
    if (tex < 0 || mesh.uvs.empty()) return;  // no st: no tangent frame, the map cannot apply
    // Tangent frame from the st parameterisation: dp/ds and dp/dt of the triangle (they do
    // not depend on the corner order, so flattened and instanced copies agree).
    const uint32_t prim = hit->prim_id;
    Vec3 p[3];
    for (int c = 0; c < 3; ++c) p[c] = LocalVertex(mesh.positions, mesh.indices, prim, c);
    const float* uv = &mesh.uvs[6 * size_t(prim)];
    const Vec3 e1 = p[1] - p[0], e2 = p[2] - p[0];
    const float du1 = uv[2] - uv[0], dv1 = uv[3] - uv[1], du2 = uv[4] - uv[0], dv2 = uv[5] - uv[1];
    const float det = du1 * dv2 - du2 * dv1;
    if (!(std::abs(det) > 1e-20f)) return;  // degenerate st: no frame
    Vec3 dpds = (e1 * dv2 - e2 * dv1) / det, dpdt = (e2 * du1 - e1 * du2) / det;
    if (hit->instance != kNoInstance) {
        dpds = TransformVector(instances_[hit->instance].m, dpds);
        dpdt = TransformVector(instances_[hit->instance].m, dpdt);
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
    if (hit.geom_id != kTriangleGeometry) return false;
    const uint32_t mi = meshes_[hit.mesh].material[hit.prim_id];
    if (!material_is_cutout_[mi]) return false;
    const Material& m = materials_[mi];
    const int32_t t = m.textures[kSlotOpacity];
    if (IsPresenceMode(*m.preview)) {
        const float opacity = t < 0 ? m.preview->opacity : textures_.EvaluateFloat(uint32_t(t), hit.st);
        return PresenceHash(hit) >= opacity;
    }
    return t < 0 || IsCutout(*m.preview, textures_.EvaluateFloat(uint32_t(t), hit.st));
}

bool Scene::Intersect(const Ray& ray, SurfaceHit* hit, float t_min, float t_max) const {
    if (!IntersectSurface(ray, hit, t_min, t_max)) return false;
    ApplyNormalMap(hit);
    return true;
}

bool Scene::IntersectSurface(const Ray& ray, SurfaceHit* hit, float t_min, float t_max) const {
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
    hit->prim_id = rh.hit.primID;
    hit->b1 = rh.hit.u;
    hit->b2 = rh.hit.v;
    const uint32_t inst = rh.hit.instID[0];
    if (inst == RTC_INVALID_GEOMETRY_ID && rh.hit.geomID == kSphereGeometry) {
        const SphereLight& s = spheres_[rh.hit.primID];
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
    hit->geom_id = kTriangleGeometry;
    hit->instance = inst == RTC_INVALID_GEOMETRY_ID ? kNoInstance : inst - kFirstInstanceGeometry;
    hit->mesh = hit->instance == kNoInstance ? 0 : instances_[hit->instance].mesh;
    const Mesh& mesh = meshes_[hit->mesh];
    const uint32_t prim = rh.hit.primID;
    // Recompute the hit point from barycentrics: smaller error than o + t d far away.
    const Vec3 p0 = LocalVertex(mesh.positions, mesh.indices, prim, 0),
               p1 = LocalVertex(mesh.positions, mesh.indices, prim, 1),
               p2 = LocalVertex(mesh.positions, mesh.indices, prim, 2);
    const float u = rh.hit.u, v = rh.hit.v;
    float p_error;
    Vec3 p = TrianglePoint(p0, p1, p2, u, v, &p_error);
    Vec3 ng = Cross(p1 - p0, p2 - p0);
    Vec3 ns(0.f);
    if (!mesh.normals.empty()) {
        const float* n = &mesh.normals[9 * size_t(prim)];
        ns = Vec3(n[0], n[1], n[2]) * (1.f - u - v) + Vec3(n[3], n[4], n[5]) * u + Vec3(n[6], n[7], n[8]) * v;
    }
    if (hit->instance != kNoInstance) {
        // Points by the transform, normals by its inverse transpose. With a mirroring
        // transform the inverse transpose keeps the normal on the side the flattened copy
        // (whose winding is reversed) faces.
        const Instance& in = instances_[hit->instance];
        p_error = TransformedPointError(in.m, p, p_error);
        p = TransformPoint(in.m, p);
        ng = TransformNormal(in.n, ng);
        ns = TransformNormal(in.n, ns);
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
    hit->st = TriangleST(mesh, prim, u, v);
    return true;
}

bool Scene::Occluded(Vec3 origin, Vec3 dir, float t_far) const {
    if (has_cutouts_) {
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
    ray.time = 0.f;
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

const Material& Scene::MaterialAt(const SurfaceHit& hit) const {
    static const Material kLightSurface{Color(0.f), Color(0.f), false, std::nullopt};
    return hit.geom_id == kTriangleGeometry ? MaterialOf(hit.mesh, hit.prim_id) : kLightSurface;
}

BSDF Scene::BSDFAt(const SurfaceHit& hit, TransportMode mode) const {
    if (hit.geom_id != kTriangleGeometry) return BSDF();
    const uint32_t mi = meshes_[hit.mesh].material[hit.prim_id];
    const Material& m = materials_[mi];
    if (!m.preview) return BSDF(DiffuseBSDF(m.albedo));
    if (!material_has_textures_[mi]) return MakePreviewSurfaceBSDF(*m.preview, mode);
    MaterialParams p = *m.preview;  // a copy on the stack, textured inputs evaluated at st
    ApplyTextures(m, hit.st, &p);
    return MakePreviewSurfaceBSDF(p, mode);
}

int32_t Scene::EmitterAt(const SurfaceHit& hit) const {
    if (hit.geom_id != kTriangleGeometry) return sphere_emitter_[hit.prim_id];
    const int32_t local = meshes_[hit.mesh].emitter[hit.prim_id];
    if (hit.instance == kNoInstance || local < 0) return local;
    return instances_[hit.instance].emitter_base + local;
}

Color Scene::Emitted(int32_t emitter, const SurfaceHit& hit, Vec3 wo) const {
    if (emitter < 0) return Color(0.f);
    const Emitter& e = emitters_[emitter];
    if (e.kind == LightKind::kSphere) return spheres_[e.index].radiance;
    const Material& m = MaterialOf(e.mesh, e.index);
    if (!m.two_sided_emission && !(Dot(hit.ng, wo) > 0.f)) return Color(0.f);
    return TriangleEmission(e.mesh, e.index, hit.b1, hit.b2);
}

TriangleLight Scene::TriangleLightOf(const Emitter& e) const {
    TriangleLight t;
    Vec3 tri[3];
    t.orientation = TriangleVertices(e.mesh, e.index, e.instance, tri);
    t.p0 = tri[0];
    t.p1 = tri[1];
    t.p2 = tri[2];
    t.area = e.area;
    t.two_sided = MaterialOf(e.mesh, e.index).two_sided_emission;
    t.instanced = e.instance != kNoInstance;
    return t;
}

bool Scene::SampleEmitter(uint32_t emitter, Vec3 ref, Vec2 u, LightSample* out) const {
    const Emitter& e = emitters_[emitter];
    out->is_delta = false;
    switch (e.kind) {
        case LightKind::kPoint: return points_[e.index].Sample(ref, out);
        case LightKind::kDistant: return distants_[e.index].Sample(u, e.one_minus_cos, out);
        case LightKind::kDome: return dome_.SampleLight(u, out);
        case LightKind::kSphere: return spheres_[e.index].Sample(ref, u, out);
        case LightKind::kTriangle:
            return TriangleLightOf(e).Sample(
                ref, u, [&](float b1, float b2) { return TriangleEmission(e.mesh, e.index, b1, b2); }, out);
    }
    return false;
}

bool Scene::SampleEmission(uint32_t emitter, Vec2 u_pos, Vec2 u_dir, float u_side, EmissionSample* out) const {
    const Emitter& e = emitters_[emitter];
    out->on_surface = false;
    switch (e.kind) {
        case LightKind::kTriangle:
            return TriangleLightOf(e).SampleEmission(
                u_pos, u_dir, u_side, [&](float b1, float b2) { return TriangleEmission(e.mesh, e.index, b1, b2); },
                out);
        case LightKind::kSphere: return spheres_[e.index].SampleEmission(u_pos, u_dir, e.area, out);
        case LightKind::kPoint: return points_[e.index].SampleEmission(u_dir, out);
        case LightKind::kDistant:
        case LightKind::kDome: {
            float pdf_dir = 1.f;
            Color L;
            Vec3 wo;
            if (e.kind == LightKind::kDome) {
                wo = -dome_.Sample(u_dir, &pdf_dir, &L);  // light travels away from the dome
                if (!(pdf_dir > 0.f)) return false;
            } else {
                distants_[e.index].SampleEmissionDirection(u_dir, e.one_minus_cos, &wo, &pdf_dir, &L);
            }
            SampleInfiniteEmission(wo, pdf_dir, L, u_pos, scene_center_, scene_radius_, out);
            out->delta_light = e.kind == LightKind::kDistant && e.one_minus_cos == 0.f;
            return true;
        }
    }
    return false;
}

float Scene::EmissionPdfDirection(uint32_t emitter, Vec3 n, Vec3 w) const {
    const Emitter& e = emitters_[emitter];
    switch (e.kind) {
        case LightKind::kPoint: return PointLight::PdfDirection();
        case LightKind::kSphere: return SphereLight::PdfDirection(n, w);
        case LightKind::kTriangle:
            return TriangleLightPdfDirection(MaterialOf(e.mesh, e.index).two_sided_emission, n, w);
        case LightKind::kDistant: return DistantLight::PdfDirection(e.one_minus_cos);
        case LightKind::kDome: return dome_.PdfDirection(w);
    }
    return 0.f;
}

float Scene::EmissionPdfPosition(uint32_t emitter) const {
    const Emitter& e = emitters_[emitter];
    switch (e.kind) {
        case LightKind::kPoint: return PointLight::PdfPosition();
        case LightKind::kSphere:
        case LightKind::kTriangle: return 1.f / e.area;
        case LightKind::kDistant:
        case LightKind::kDome: return InfiniteEmissionPdfPosition(scene_radius_);
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

Color Scene::EnvironmentRadiance(const Emitter& e, Vec3 dir, float* pdf) const {
    if (e.kind == LightKind::kDome) return dome_.Radiance(dir, pdf);
    return distants_[e.index].Radiance(dir, e.one_minus_cos, pdf);
}

float Scene::EmitterPdf(uint32_t emitter, Vec3 ref, const SurfaceHit& hit) const {
    const Emitter& e = emitters_[emitter];
    if (e.kind == LightKind::kSphere) return spheres_[e.index].Pdf(ref);
    return TriangleLightPdf(ref, hit.p, hit.ng, e.area);
}

}  // namespace tessera
