#include "scene.h"

#include <algorithm>

#include <atomic>
#include <cstring>
#include <limits>
#include <map>
#include <stdexcept>
#include <cstdlib>
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

// A UsdPreviewSurface that equals a Lambertian exactly (bsdf.h, ExactLambertianAlbedo) is
// made one, so that it costs what it is and a scene of them keeps the Lambertian kernel.
// An emission texture stays: a Lambertian may carry one.
void MakeExactLambertian(Material& mat) {
    if (!mat.preview) return;
    for (int slot = 0; slot < kNumTextureSlots; ++slot)
        if (slot != kSlotEmissiveColor && mat.textures[slot] >= 0) return;
    if (std::optional<Color> rho = ExactLambertianAlbedo(*mat.preview)) {
        mat.albedo = *rho;
        mat.preview.reset();
    }
}

// The Lambert-only build (feature_set.h) has no code for anything else: it refuses it.
// `materials` are the scene's, after MakeExactLambertian.
void RequireLambertOnly(const SceneDesc& d, const std::vector<Material>& materials) {
    auto refuse = [](const std::string& what) {
        throw std::invalid_argument("this renderer build (TESSERA_LAMBERT_ONLY) renders Lambertian triangles "
                                    "under triangle lights only; the scene has " + what);
    };
    for (size_t m = 0; m < materials.size(); ++m) {
        const Material& mat = materials[m];
        if (mat.preview) refuse("a UsdPreviewSurface (material " + std::to_string(m) + ")");
        if (mat.textures != NoTextures()) refuse("textures (material " + std::to_string(m) + ")");
        if (mat.emission_shaping >= 0) refuse("a shaped light (material " + std::to_string(m) + ")");
        if (mat.light_link >= 0) refuse("light links (material " + std::to_string(m) + ")");
    }
    if (!d.uvs.empty()) refuse("texture coordinates");
    if (!d.prototypes.empty() || !d.instance_prototype.empty()) refuse("instances");
    if (!d.motion_instances.empty() || !d.light_motion_kinds.empty()) refuse("motion");
    if (!d.curve_segments.empty()) refuse("curves");
    if (!d.media.empty()) refuse("participating media");
    if (!d.sphere_lights.empty() || !d.point_lights.empty() || !d.distant_lights.empty() ||
        !IsBlack(d.dome_radiance))
        refuse("lights other than emissive triangles");
    for (const std::vector<float>& rows : d.light_rows)
        if (!rows.empty()) refuse("lights other than emissive triangles");
}

// A sphere light is seen, and blocks rays, from outside only: UsdLux sphere lights emit
// outward, and a ray leaving a point inside one (a camera or an object within its radius)
// passes through it. Embree reports such a ray's exit through the inside of the sphere, a
// hit whose normal faces along the ray: it is rejected here (closest and occlusion
// queries alike), so the ray goes on. A ray from outside meets the outside first and is
// stopped there as before. Light sampling agrees: from inside there is none (SphereLight::Sample).
void SphereOutsideOnly(const RTCFilterFunctionNArguments* args) {
    for (unsigned i = 0; i < args->N; ++i) {
        if (args->valid[i] != -1) continue;
        const float dot = RTCHitN_Ng_x(args->hit, args->N, i) * RTCRayN_dir_x(args->ray, args->N, i) +
                          RTCHitN_Ng_y(args->hit, args->N, i) * RTCRayN_dir_y(args->ray, args->N, i) +
                          RTCHitN_Ng_z(args->hit, args->N, i) * RTCRayN_dir_z(args->ray, args->N, i);
        if (dot > 0.f) args->valid[i] = 0;
    }
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

namespace {
std::string Trim(const std::string& s) {
    const size_t first = s.find_first_not_of(" \t");
    return first == std::string::npos ? std::string() : s.substr(first, s.find_last_not_of(" \t") - first + 1);
}
}  // namespace

RTCDevice EmbreeDevice() {
    static RTCDevice device = [] {
        // TESSERA_EMBREE_CONFIG adds to Embree's device configuration, e.g. "isa=sse4.2":
        // Embree picks its SIMD code per CPU, so a farm of mixed CPUs pins one ISA that
        // way (docs/farm.md, "Determinism").
        std::string config = "verbose=0";
        if (const char* extra = std::getenv("TESSERA_EMBREE_CONFIG"); extra && *extra) {
            // Items are passed on as key=value without spaces, which Embree would not read
            // (it ignores "isa = avx2" without a word), and an ISA name Embree does not know,
            // on which it falls back to SSE2 silently, is refused.
            const std::string settings = extra;
            for (size_t begin = 0; begin <= settings.size();) {
                const size_t end = std::min(settings.find(',', begin), settings.size());
                const std::string item = Trim(settings.substr(begin, end - begin));
                begin = end + 1;
                if (item.empty()) continue;
                const size_t eq = item.find('=');
                if (eq == std::string::npos) {
                    config += "," + item;
                    continue;
                }
                const std::string key = Trim(item.substr(0, eq)), value = Trim(item.substr(eq + 1));
                static const char* const known[] = {"sse2", "sse4.2", "avx", "avx2", "avx512", "avx512knl",
                                                    "avx512skx"};
                if ((key == "isa" || key == "max_isa") &&
                    std::find(std::begin(known), std::end(known), value) == std::end(known))
                    throw std::runtime_error("TESSERA_EMBREE_CONFIG: unknown ISA '" + value +
                                             "' (known: sse2, sse4.2, avx, avx2, avx512)");
                config += "," + key + "=" + value;
            }
        }
        RTCDevice d = rtcNewDevice(config.c_str());
        if (!d)
            throw std::runtime_error("cannot create the Embree device (configuration '" + config +
                                     "'; TESSERA_EMBREE_CONFIG adds to it)");
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
      emission_shapings_(desc.emission_shapings) {
    lights_.Of<SphereLight>() = desc.sphere_lights;
    lights_.Of<PointLight>() = desc.point_lights;
    lights_.Of<DistantLight>() = desc.distant_lights;
    std::vector<SphereLight>& spheres = lights_.Of<SphereLight>();
    std::vector<PointLight>& points = lights_.Of<PointLight>();
    std::vector<DistantLight>& distants = lights_.Of<DistantLight>();
    for (Material& mat : materials_) MakeExactLambertian(mat);
    if constexpr (!kFullFeatures) RequireLambertOnly(desc, materials_);
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
            // Textures drive UsdPreviewSurface inputs; a plain Lambertian has none to drive
            // but its emission (a RectLight's texture).
            if (t >= 0 && !materials_[m].preview && slot != kSlotEmissiveColor) materials_[m].textures[slot] = -1;
        }
        material_has_textures_.push_back(materials_[m].textures != NoTextures());
        if (materials_[m].emission_shaping < -1 ||
            materials_[m].emission_shaping >= int64_t(emission_shapings_.size()))
            throw std::invalid_argument("material " + std::to_string(m) + " refers to emission shaping " +
                                        std::to_string(materials_[m].emission_shaping) + " of " +
                                        std::to_string(emission_shapings_.size()));
        // Cutout by the material's own opacity, or possibly by its opacity texture (then
        // decided per hit in IsCutoutHit).
        const auto& pv = materials_[m].preview;
        const bool textured_opacity = materials_[m].textures[kSlotOpacity] >= 0;
        material_is_cutout_.push_back(
            pv && (IsPresenceMode(*pv) ? textured_opacity || pv->opacity < 1.f
                                       : textured_opacity ? pv->opacity_threshold > 0.f
                                                          : IsCutout(*pv, pv->opacity)));
        has_cutouts_ = has_cutouts_ || material_is_cutout_.back();
        all_lambertian_ = all_lambertian_ && !pv;
        has_normal_maps_ = has_normal_maps_ || (pv && materials_[m].textures[kSlotNormal] >= 0);
        // An untextured material's BSDF is the same at every hit: built here once per
        // transport mode, copied by BSDFAt (its constructor costs more than the copy).
        // Its angle-only terms are tabulated once too (preview_surface_bsdf.h, PreviewSurfaceTable).
        for (TransportMode mode : {TransportMode::Radiance, TransportMode::Importance}) {
            material_bsdfs_.push_back(!pv ? BSDF(DiffuseBSDF(materials_[m].albedo))
                                      : material_has_textures_.back() ? BSDF()
                                                                      : MakePreviewSurfaceBSDF(*pv, mode));
            if (PreviewSurfaceBSDF* ps = material_bsdfs_.back().GetIf<PreviewSurfaceBSDF>()) {
                preview_tables_.push_back(std::make_unique<PreviewSurfaceTable>(ps->Tabulate()));
                ps->UseTable(preview_tables_.back().get());
            }
        }
        // A textured material may have a delta lobe where a texture sets its roughness to 0.
        const auto& tex = materials_[m].textures;
        material_may_have_delta_.push_back(
            pv && (MakePreviewSurfaceBSDF(*pv, TransportMode::Radiance).HasDelta() ||
                   (material_has_textures_.back() && (tex[kSlotRoughness] >= 0 || tex[kSlotClearcoatRoughness] >= 0))));
    }
    for (size_t s = 0; s < spheres.size(); ++s)
        if (!IsFinite(spheres[s].center) || !(spheres[s].radius > 0.f) || !std::isfinite(spheres[s].radius) ||
            !IsNonNegativeFinite(spheres[s].radiance))
            throw std::invalid_argument("sphere light " + std::to_string(s) + " has a bad centre, radius or radiance");
    for (size_t i = 0; i < points.size(); ++i)
        if (!IsFinite(points[i].position) || !IsNonNegativeFinite(points[i].intensity))
            throw std::invalid_argument("point light " + std::to_string(i) + " has a bad position or intensity");
    for (size_t i = 0; i < distants.size(); ++i) {
        DistantLight& d = distants[i];
        float len = Length(d.direction);
        if (!IsFinite(d.direction) || !(len > 0.f) || !(d.half_angle >= 0.f) || !(d.half_angle < 0.5f * kPi) ||
            !IsNonNegativeFinite(d.radiance))
            throw std::invalid_argument("distant light " + std::to_string(i) +
                                        " needs a direction, a half angle in [0, pi/2) and radiance >= 0");
        d.direction = d.direction / len;
    }
    // The kinds handed over in rows (kRowColumnsOf), each row checked by its kind.
    if (desc.light_rows.size() > LightKinds::kCount) throw std::invalid_argument("light_rows has more kinds than the core");
    ForEachLightKind([&](auto kind) {
        using Kind = typename decltype(kind)::type;
        constexpr size_t columns = kRowColumnsOf<Kind>;
        const size_t k = size_t(kKindOf<Kind>);
        if (k >= desc.light_rows.size() || desc.light_rows[k].empty()) return;
        if constexpr (columns == 0) {
            throw std::invalid_argument(std::string(EmitterOf<Kind>::kName) + " lights are not handed over in rows");
        } else {
            const std::vector<float>& rows = desc.light_rows[k];
            if (rows.size() % columns != 0)
                throw std::invalid_argument(std::string(EmitterOf<Kind>::kName) + " light rows need " +
                                            std::to_string(columns) + " columns");
            for (size_t r = 0; r < rows.size(); r += columns) {
                try {
                    lights_.Of<Kind>().push_back(EmitterOf<Kind>::FromRow(&rows[r]));
                } catch (const std::invalid_argument& e) {
                    throw std::invalid_argument(std::string(EmitterOf<Kind>::kName) + " light " +
                                                std::to_string(r / columns) + ": " + e.what());
                }
            }
        }
    });
    if (!IsNonNegativeFinite(desc.dome_radiance)) throw std::invalid_argument("dome radiance must be finite and >= 0");
    // Built in place: a copy would hold the texture and its distribution twice at once.
    lights_.Of<DomeLight>().emplace_back(desc.dome_radiance, desc.dome_width, desc.dome_height, desc.dome_rgb,
                                         desc.dome_world_to_light);

    // From here on Embree objects exist: a throw must release them, since a constructor
    // that throws never runs its destructor.
    try {
        BuildGeometryAndLights(desc);
        BuildMedia(desc);
    } catch (...) {
        ReleaseEmbree();
        throw;
    }
    BoundDeltaSurfaces();
}

void Scene::BoundDeltaSurfaces() {
    if (has_motion() || !has_delta_surfaces()) return;
    for (uint32_t m : curve_material_)
        if (material_may_have_delta_[m]) return;  // not bounded here: photons are not aimed then
    auto is_delta = [&](uint32_t mesh, uint32_t prim) {
        return material_may_have_delta_[meshes_[mesh].material[prim]] != 0;
    };
    constexpr float kInf = std::numeric_limits<float>::infinity();
    Vec3 lo(kInf, kInf, kInf), hi(-kInf, -kInf, -kInf);
    ForEachTriangle([&](uint32_t mesh, uint32_t prim, uint32_t, const Vec3* p, float) {
        if (!is_delta(mesh, prim)) return;
        for (int k = 0; k < 3; ++k) {
            lo = Vec3(std::min(lo.x, p[k].x), std::min(lo.y, p[k].y), std::min(lo.z, p[k].z));
            hi = Vec3(std::max(hi.x, p[k].x), std::max(hi.y, p[k].y), std::max(hi.z, p[k].z));
        }
    });
    if (!(lo.x <= hi.x)) return;  // the delta materials are on curves or unused
    const Vec3 c = (lo + hi) * 0.5f;
    float r2 = 0.f;
    ForEachTriangle([&](uint32_t mesh, uint32_t prim, uint32_t, const Vec3* p, float) {
        if (!is_delta(mesh, prim)) return;
        for (int k = 0; k < 3; ++k) r2 = std::max(r2, LengthSquared(p[k] - c));
    });
    delta_center_ = c;
    // Slightly beyond the farthest corner, so rounding never leaves a corner outside.
    delta_radius_ = std::sqrt(r2) * (1.f + 1e-4f) + 1e-6f * (MaxAbsComponent(c) + 1.f);
}

// Round linear curves: each segment a cone between two spheres (Embree 3), the whole
// strand a smooth tube without the facets or the triangle count of a mesh. World space
// and still: moving or instanced curves come as triangle tubes (tessera_renderer.usd).
void Scene::BuildCurves(const SceneDesc& desc, RTCDevice device) {
    const size_t n_points = desc.curve_points.size() / 4, n_segments = desc.curve_segments.size();
    if (desc.curve_points.size() % 4 != 0) throw std::invalid_argument("curve_points must hold 4 floats per point");
    if (desc.curve_material.size() != n_segments || desc.curve_flags.size() != n_segments)
        throw std::invalid_argument("curves need one material and one flag per segment");
    if (n_segments == 0) return;
    for (size_t i = 0; i < n_points; ++i) {
        const float* q = &desc.curve_points[4 * i];
        if (!std::isfinite(q[0]) || !std::isfinite(q[1]) || !std::isfinite(q[2]) || !(q[3] >= 0.f) ||
            !std::isfinite(q[3]))
            throw std::invalid_argument("curve point " + std::to_string(i) + " needs a finite position and radius >= 0");
    }
    for (size_t k = 0; k < n_segments; ++k) {
        if (size_t(desc.curve_segments[k]) + 1 >= n_points)
            throw std::invalid_argument("curve segment " + std::to_string(k) + " starts past the last point");
        if (desc.curve_material[k] >= materials_.size())
            throw std::invalid_argument("curve segment " + std::to_string(k) + " refers to material " +
                                        std::to_string(desc.curve_material[k]) + " of " +
                                        std::to_string(materials_.size()));
    }
    curve_material_ = desc.curve_material;
    curve_first_ = desc.curve_segments;
    curve_radius_.resize(n_points);
    for (size_t i = 0; i < n_points; ++i) curve_radius_[i] = desc.curve_points[4 * i + 3];
    RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_ROUND_LINEAR_CURVE);
    auto* vb = static_cast<float*>(
        rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, 4 * sizeof(float), n_points));
    auto* ib = static_cast<uint32_t*>(
        rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT, sizeof(uint32_t), n_segments));
    auto* fb = static_cast<uint8_t*>(
        rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_FLAGS, 0, RTC_FORMAT_UCHAR, sizeof(uint8_t), n_segments));
    CheckDevice(device, "allocating curve buffers");
    std::copy(desc.curve_points.begin(), desc.curve_points.end(), vb);
    std::copy(desc.curve_segments.begin(), desc.curve_segments.end(), ib);
    std::copy(desc.curve_flags.begin(), desc.curve_flags.end(), fb);
    rtcCommitGeometry(geom);
    rtcAttachGeometryByID(scene_, geom, kCurveGeometry);
    rtcReleaseGeometry(geom);
    CheckDevice(device, "building curves");
}

// The BVHs (the world's, one per prototype, the instances), then the light table.
void Scene::BuildGeometryAndLights(const SceneDesc& desc) {
    const std::vector<SphereLight>& spheres = lights_.Of<SphereLight>();
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
              desc.indices.size() / 3, desc.triangle_material, desc.shading_normals, desc.uvs, {}, scene_,
              kTriangleGeometry, "");
    BuildLightMotion(desc);
    BuildCurves(desc, device);
    if (!spheres.empty()) {
        RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_SPHERE_POINT);
        // Moving spheres all have the same step count (BuildLightMotion): one vertex buffer
        // per step, each sphere where its motion puts it then.
        uint32_t steps = 1;
        for (const LightMotion& m : light_motions_.Of<SphereLight>()) steps = std::max(steps, m.time_steps);
        if (steps > 1) rtcSetGeometryTimeStepCount(geom, steps);
        for (uint32_t k = 0; k < steps; ++k) {
            auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, k, RTC_FORMAT_FLOAT4,
                                                                   4 * sizeof(float), spheres.size()));
            CheckDevice(device, "allocating sphere buffers");
            for (size_t s = 0; s < spheres.size(); ++s) {
                const LightMotion& m = light_motions_.Of<SphereLight>()[s];
                const Vec3 c = m.time_steps > 1
                                   ? TransformPoint(&light_motion_m_[12 * size_t(m.first_step + k)], spheres[s].center)
                                   : spheres[s].center;
                vb[4 * s + 0] = c.x;
                vb[4 * s + 1] = c.y;
                vb[4 * s + 2] = c.z;
                vb[4 * s + 3] = spheres[s].radius;
            }
        }
        rtcSetGeometryIntersectFilterFunction(geom, SphereOutsideOnly);
        rtcSetGeometryOccludedFilterFunction(geom, SphereOutsideOnly);
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
                  pd.triangle_material, pd.shading_normals, pd.uvs, pd.motion_positions, mesh.scene, 0, what);
        has_deformation_ = has_deformation_ || mesh.time_steps > 1;
        rtcCommitScene(mesh.scene);
        CheckDevice(device, "building a prototype BVH");
    }
    const size_t num_instances = desc.instance_prototype.size();
    if (desc.instance_transforms.size() != 12 * num_instances)
        throw std::invalid_argument("instance_transforms must hold one 3x4 matrix per instance");
    instances_.resize(num_instances);
    // Moving instances: instance -> (its first matrix in motion_transforms, its step count).
    if (desc.motion_instances.size() != desc.motion_time_steps.size())
        throw std::invalid_argument("motion_instances and motion_time_steps must have one entry each per moving instance");
    std::map<uint32_t, std::pair<size_t, uint32_t>> motion_steps;
    size_t motion_total = 0;
    for (size_t k = 0; k < desc.motion_instances.size(); ++k) {
        const uint32_t inst = desc.motion_instances[k], steps = desc.motion_time_steps[k];
        if (inst >= num_instances || steps < 2 || steps > kMaxTimeSteps ||
            !motion_steps.emplace(inst, std::make_pair(motion_total, steps)).second)
            throw std::invalid_argument("moving instance " + std::to_string(inst) + ": needs an instance index below " +
                                        std::to_string(num_instances) + ", listed once, with 2 to " +
                                        std::to_string(kMaxTimeSteps) + " time steps (got " + std::to_string(steps) + ")");
        motion_total += steps;
    }
    if (desc.motion_transforms.size() != 12 * motion_total)
        throw std::invalid_argument("motion_transforms must hold one 3x4 matrix per time step of every moving instance");
    num_triangles_ = meshes_[0].num_triangles;
    for (size_t i = 0; i < num_instances; ++i) {
        const uint32_t proto = desc.instance_prototype[i];
        if (proto >= desc.prototypes.size())
            throw std::invalid_argument("instance " + std::to_string(i) + " refers to prototype " +
                                        std::to_string(proto) + " of " + std::to_string(desc.prototypes.size()));
        Instance& inst = instances_[i];
        inst.mesh = 1 + proto;
        std::copy(desc.instance_transforms.begin() + 12 * i, desc.instance_transforms.begin() + 12 * (i + 1), inst.m);
        auto check = [&](const float* m, float* n) {
            bool finite = true;
            for (int j = 0; j < 12; ++j) finite = finite && std::isfinite(m[j]);
            float scratch[9];
            const double det = NormalMatrixOf(m, n ? n : scratch);
            if (!finite || !(std::abs(det) > 1e-30) || !std::isfinite(det))
                throw std::invalid_argument("instance " + std::to_string(i) +
                                            " has a non-finite or singular transform");
            return det;
        };
        inst.orientation = check(inst.m, inst.n) < 0.0 ? -1.f : 1.f;
        if (auto it = motion_steps.find(uint32_t(i)); it != motion_steps.end()) {
            inst.time_steps = it->second.second;
            inst.first_step = uint32_t(motion_m_.size() / 12);
            const float* steps = desc.motion_transforms.data() + 12 * size_t(it->second.first);
            motion_m_.insert(motion_m_.end(), steps, steps + 12 * size_t(inst.time_steps));
            for (uint32_t k = 0; k < inst.time_steps; ++k) check(steps + 12 * k, nullptr);
            std::copy(steps, steps + 12, inst.m);  // the first step is the static view
            inst.orientation = check(inst.m, inst.n) < 0.0 ? -1.f : 1.f;
        }
        RTCGeometry geom = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_INSTANCE);
        rtcSetGeometryInstancedScene(geom, meshes_[inst.mesh].scene);
        if (inst.time_steps > 1) {
            rtcSetGeometryTimeStepCount(geom, inst.time_steps);
            for (uint32_t k = 0; k < inst.time_steps; ++k)
                rtcSetGeometryTransform(geom, k, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, &motion_m_[12 * size_t(inst.first_step + k)]);
        } else {
            rtcSetGeometryTransform(geom, 0, RTC_FORMAT_FLOAT3X4_ROW_MAJOR, inst.m);
        }
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
    for (const PointLight& p : lights_.Of<PointLight>()) {
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
        emitters_.push_back({kKindOf<TriangleLight>, prim, area, 0.f, mesh, instance});
        power.push_back(double(Luminance(emission_estimate[mi])) * area * kPi *
                        (materials_[mi].two_sided_emission ? 2.0 : 1.0));
    };
    // Textured emission black over a triangle's whole st footprint (an emissive map's dark
    // regions: a converted asset's trims glow, the rest is black) makes no emitter: such a
    // triangle emits exactly nothing, so leaving it out of the light sampler and of hits'
    // emission changes no expectation and saves an entry per triangle.
    auto emits_nothing = [&](const Mesh& mesh, uint32_t t) {
        if constexpr (!kFullFeatures) return false;
        const int32_t tex = materials_[mesh.material[t]].textures[kSlotEmissiveColor];
        if (tex < 0) return false;
        Vec2 st[3] = {};
        if (!mesh.uvs.empty())
            for (int c = 0; c < 3; ++c) st[c] = {mesh.uvs[6 * size_t(t) + 2 * c], mesh.uvs[6 * size_t(t) + 2 * c + 1]};
        return textures_.ZeroOverTriangle(uint32_t(tex), st);
    };
    if constexpr (kFullFeatures)
        for (size_t m = 0; m < materials_.size(); ++m)
            if (materials_[m].textures[kSlotEmissiveColor] >= 0 && !IsBlack(emission_estimate[m]))
                textures_.PrepareZeroTest(uint32_t(materials_[m].textures[kSlotEmissiveColor]));
    for (size_t k = 0; k < meshes_.size(); ++k) {
        Mesh& mesh = meshes_[k];
        mesh.emitter.assign(mesh.num_triangles, kNoEmitter);
        for (uint32_t t = 0; t < mesh.num_triangles; ++t) {
            if (IsBlack(emission_estimate[mesh.material[t]]) || emits_nothing(mesh, t)) continue;
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
    textures_.ReleaseZeroTests();
    // Every instance of a prototype with emissive triangles is a light of its own.
    for (uint32_t i = 0; i < instances_.size(); ++i) {
        const Mesh& mesh = meshes_[instances_[i].mesh];
        if (mesh.num_emissive == 0) continue;
        instances_[i].emitter_base = int32_t(emitters_.size());
        for (uint32_t t = 0; t < mesh.num_triangles; ++t)
            if (mesh.emitter[t] >= 0) add_triangle_emitter(instances_[i].mesh, t, i);
    }
    // Every other kind adds its own emitters, in LightKinds order; a kind whose light
    // another kind's lights carry (the dome through portals) adds none when there are some.
    ForEachLightKind([&](auto kind) {
        using Kind = typename decltype(kind)::type;
        bool guided = false;
        ForEachLightKind([&](auto guide) {
            using Guide = typename decltype(guide)::type;
            if constexpr (kGuides<Guide, Kind>) guided = guided || !lights_.Of<Guide>().empty();
        });
        if (guided) return;
        const size_t before = emitters_.size();
        EmitterOf<Kind>::AddEmitters(*this, [&](uint32_t index, float area, float one_minus_cos, double p, bool at_infinity) {
            if (at_infinity) environment_lights_.push_back(uint32_t(emitters_.size()));
            emitters_.push_back({kKindOf<Kind>, index, area, one_minus_cos});
            power.push_back(p);
        });
        if (!kStartsLightPathsOf<Kind> && emitters_.size() > before) kind_without_light_paths_ = EmitterOf<Kind>::kName;
    });
    sphere_emitter_.assign(lights_.Of<SphereLight>().size(), kNoEmitter);
    for (uint32_t i = 0; i < emitters_.size(); ++i)
        if (emitters_[i].kind == kKindOf<SphereLight>) sphere_emitter_[emitters_[i].index] = int32_t(i);
    light_sampler_ = LightSampler(power);
    if constexpr (kFullFeatures) BuildLightLinks(desc);  // before the BVH, which leaves linked lights out
    BuildLightBVH(power, desc.light_selection);
    if (kFullFeatures && has_light_links_) BuildGroupLights(power);
    // Triangle lights that stand still, resolved once (corners, area, sidedness): next event
    // estimation asks for one at every vertex. 48 bytes per emitter.
    if (motion_m_.empty() && !has_deformation_) {
        still_triangle_lights_.resize(emitters_.size());
        for (size_t i = 0; i < emitters_.size(); ++i)
            if (emitters_[i].kind == kKindOf<TriangleLight>) still_triangle_lights_[i] = ResolveTriangleLight(emitters_[i]);
    }

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

void Scene::BuildLightMotion(const SceneDesc& desc) {
    const size_t n = desc.light_motion_kinds.size();
    if (desc.light_motion_indices.size() != n || desc.light_motion_time_steps.size() != n)
        throw std::invalid_argument("light_motion_kinds, _indices and _time_steps need one entry each per moving light");
    ForEachLightKind([&](auto kind) {
        using Kind = typename decltype(kind)::type;
        if constexpr (EmitterOf<Kind>::kMoves) light_motions_.Of<Kind>().assign(lights_.Of<Kind>().size(), {});
    });
    // Moving spheres share the sphere geometry's steps: the largest count among them.
    uint32_t sphere_steps = 0;
    for (size_t k = 0; k < n; ++k)
        if (desc.light_motion_kinds[k] == kKindOf<SphereLight>)
            sphere_steps = std::max(sphere_steps, desc.light_motion_time_steps[k]);
    size_t offset = 0;
    for (size_t k = 0; k < n; ++k) {
        const LightKind kind = desc.light_motion_kinds[k];
        const uint32_t index = desc.light_motion_indices[k], steps = desc.light_motion_time_steps[k];
        const std::string what = "moving light " + std::to_string(k) + ": ";
        LightMotion* slot = nullptr;
        if (uint8_t(kind) < LightKinds::kCount)
            VisitLightKind(kind, [&](auto tag) {
                using Kind = typename decltype(tag)::type;
                if constexpr (EmitterOf<Kind>::kMoves)
                    if (index < light_motions_.Of<Kind>().size()) slot = &light_motions_.Of<Kind>()[index];
            });
        if (!slot) throw std::invalid_argument(what + "no such light of a kind that moves (" + MovingKindNames() + ")");
        if (slot->time_steps > 1) throw std::invalid_argument(what + "the light is listed twice");
        if (steps < 2 || steps > kMaxTimeSteps)
            throw std::invalid_argument(what + "needs 2 to " + std::to_string(kMaxTimeSteps) + " time steps");
        if (desc.light_motion_transforms.size() < 12 * (offset + steps))
            throw std::invalid_argument("light_motion_transforms must hold one 3x4 matrix per step of every moving light");
        const float* m = desc.light_motion_transforms.data() + 12 * offset;
        for (size_t j = 0; j < 12 * size_t(steps); ++j)
            if (!std::isfinite(m[j])) throw std::invalid_argument(what + "a transform is not finite");
        for (uint32_t j = 0; j < steps; ++j) {
            float normals[9];
            const double det = NormalMatrixOf(m + 12 * j, normals);
            if (!(std::abs(det) > 1e-12)) throw std::invalid_argument(what + "a transform is singular");
        }
        const uint32_t stored = kind == kKindOf<SphereLight> ? sphere_steps : steps;
        *slot = {stored, uint32_t(light_motion_m_.size() / 12)};
        for (uint32_t j = 0; j < stored; ++j) {
            // Resampling at the shared count: this light's own matrix at that step's instant.
            float scratch[12];
            const ShutterTimeScope at(stored > 1 ? float(j) / float(stored - 1) : 0.f);
            const float* mj = MatrixAtShutterTime(m, steps, scratch);
            light_motion_m_.insert(light_motion_m_.end(), mj, mj + 12);
        }
        offset += steps;
    }
    if (desc.light_motion_transforms.size() != 12 * offset)
        throw std::invalid_argument("light_motion_transforms must hold one 3x4 matrix per step of every moving light");
}

const float* Scene::MovingLightAt(const LightMotion& motion, float* scratch, float* n_scratch) const {
    const float* m = MatrixAtShutterTime(&light_motion_m_[12 * size_t(motion.first_step)], motion.time_steps, scratch);
    // The steps were checked, and a blend of nearby rotations stays near one; a singular
    // blend (a half turn between two steps) keeps the identity for the inverse.
    for (int j = 0; j < 9; ++j) n_scratch[j] = j % 4 == 0 ? 1.f : 0.f;
    NormalMatrixOf(m, n_scratch);
    return m;
}

const Scene::LightMotion& Scene::MotionOf(const Emitter& e) const {
    static const LightMotion still;
    return VisitLightKind(e.kind, [&](auto kind) -> const LightMotion& {
        using Kind = typename decltype(kind)::type;
        if constexpr (EmitterOf<Kind>::kMoves) return light_motions_.Of<Kind>()[e.index];
        else return still;
    });
}

SphereLight Scene::SphereAt(uint32_t s) const {
    float m[12], n[9];
    SphereLight light = lights_.Of<SphereLight>()[s];
    if (const float* xf = LightMotionAt(light_motions_.Of<SphereLight>()[s], m, n)) light.center = TransformPoint(xf, light.center);
    return light;
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
                      const std::vector<float>& uvs, const std::vector<float>& motion_positions, RTCScene target,
                      uint32_t geom_id, const std::string& what) {
    if (material.size() != num_triangles)
        throw std::invalid_argument(what + "triangle_material must have one entry per triangle");
    if (num_vertices > 0xFFFFFFFFull) throw std::invalid_argument(what + "too many vertices");
    if (!normals.empty() && normals.size() != 9 * num_triangles)
        throw std::invalid_argument(what + "shading_normals must hold 3 normals per triangle");
    if (!uvs.empty() && uvs.size() != 6 * num_triangles)
        throw std::invalid_argument(what + "uvs must hold 3 st pairs per triangle");
    const size_t step_floats = 3 * num_vertices;
    if (!motion_positions.empty() &&
        (step_floats == 0 || motion_positions.size() % step_floats != 0 ||
         motion_positions.size() / step_floats + 1 > kMaxTimeSteps))
        throw std::invalid_argument(what + "motion_positions must hold 1 to " + std::to_string(kMaxTimeSteps - 1) +
                                    " further time steps of all " + std::to_string(num_vertices) + " vertices");
    const uint32_t time_steps = uint32_t(1 + (step_floats ? motion_positions.size() / step_floats : 0));
    for (uint32_t k = 0; k < time_steps; ++k) {
        const float* step = k == 0 ? positions : motion_positions.data() + (k - 1) * step_floats;
        for (size_t i = 0; i < step_floats; ++i)
            if (!std::isfinite(step[i]))
                throw std::invalid_argument(what + "vertex " + std::to_string(i / 3) + " has a non-finite coordinate" +
                                            (k ? " at time step " + std::to_string(k) : std::string()));
    }
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
    // A deforming mesh has one vertex buffer per time step (Embree's vertex slots).
    if (time_steps > 1) rtcSetGeometryTimeStepCount(geom, time_steps);
    mesh->time_steps = time_steps;
    mesh->step_positions.clear();
    for (uint32_t k = 0; k < time_steps; ++k) {
        // Embree may read 16 bytes from the last vertex, hence one vertex of padding.
        auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, k, RTC_FORMAT_FLOAT3,
                                                               3 * sizeof(float), num_vertices + 1));
        CheckDevice(device, "allocating vertex buffers");
        const float* step = k == 0 ? positions : motion_positions.data() + (k - 1) * step_floats;
        std::copy(step, step + step_floats, vb);
        vb[step_floats] = vb[step_floats + 1] = vb[step_floats + 2] = 0.f;
        mesh->step_positions.push_back(vb);
    }
    auto* ib = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                              3 * sizeof(uint32_t), num_triangles));
    CheckDevice(device, "allocating triangle buffers");
    std::copy(indices, indices + 3 * num_triangles, ib);
    mesh->positions = mesh->step_positions[0];
    mesh->indices = ib;
    rtcCommitGeometry(geom);
    rtcAttachGeometryByID(target, geom, geom_id);
    rtcReleaseGeometry(geom);
    CheckDevice(device, "attaching triangles");
}

}  // namespace tessera
