// Python binding of the renderer core: flat numpy arrays in, float RGBA tiles out.
// The GIL is released while the BVH is built and while tiles render.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/array.h>
#include <nanobind/stl/map.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <xmmintrin.h>

#include <array>
#include <atomic>
#include <chrono>
#include <limits>
#include <memory>

#include "integrator.h"
#include "render.h"
#include "scene.h"
#include "media_arrays.h"
#include "scene_arrays.h"
#include "splat_film.h"

namespace nb = nanobind;
using namespace nb::literals;
using namespace tessera;
using namespace tessera::binding;

namespace {

using CameraPoses = nb::ndarray<const float, nb::shape<-1, 12>, nb::c_contig, nb::device::cpu>;

using SplatArray = nb::ndarray<int64_t, nb::shape<-1, -1, 3>, nb::c_contig, nb::device::cpu>;
using BatchSplatArray = nb::ndarray<int64_t, nb::shape<-1, -1, -1, 3>, nb::c_contig, nb::device::cpu>;
using BatchRgbArray = nb::ndarray<float, nb::shape<-1, -1, -1, 3>, nb::c_contig, nb::device::cpu>;

SamplerKind ParseSampler(const std::string& name) {
    if (name == "sobol") return SamplerKind::kOwenSobol;
    if (name == "independent") return SamplerKind::kIndependent;
    throw std::invalid_argument("unknown sampler '" + name + "' (known: sobol, independent)");
}

// Hands a heap buffer to numpy, which frees it with the array.
nb::object ToNumpy(std::unique_ptr<float[]> buffer, std::initializer_list<size_t> shape) {
    float* data = buffer.release();
    nb::capsule owner(data, [](void* p) noexcept { delete[] static_cast<float*>(p); });
    return nb::cast(nb::ndarray<nb::numpy, float>(data, shape.size(), shape.begin(), owner));
}

}  // namespace

NB_MODULE(_core, m) {
    m.doc() = "Tessera renderer core (Embree 3 path tracer)";
    m.attr("SPLAT_SCALE") = kSplatScale;

    nb::class_<Scene>(m, "Scene")
        .def(
            "__init__",
            [](Scene* self, InArray<float, 3> positions, InArray<uint32_t, 3> indices,
               InVector<uint32_t> triangle_material, InArray<float, 3> albedo, InArray<float, 3> emission,
               InVector<bool> two_sided_emission, InArray<float, 7> sphere_lights, PointLightRows point_lights,
               InArray<float, 7> distant_lights, std::array<float, 3> dome_radiance,
               std::optional<InArray<float, 14>> preview_params, std::optional<InVector<bool>> preview_mask,
               std::optional<DomeImage> dome_texture, std::optional<InArray<float, 3>> dome_world_to_light,
               std::optional<CornerNormals> shading_normals, std::optional<CornerUVs> uvs,
               std::optional<nb::list> images, std::optional<InVector<bool>> image_srgb,
               std::optional<InArray<float, kTextureColumns>> texture_table,
               std::optional<InArray<int32_t, 100>> texture_tiles,
               std::optional<InArray<int32_t, kNumTextureSlots>> material_textures,
               std::optional<nb::list> prototypes, std::optional<InVector<uint32_t>> instance_prototype,
               std::optional<Matrices> instance_transforms, std::optional<InVector<uint32_t>> motion_instances,
               std::optional<InVector<uint32_t>> motion_time_steps, std::optional<Matrices> motion_transforms,
               std::optional<InVector<uint8_t>> light_motion_kinds,
               std::optional<InVector<uint32_t>> light_motion_indices,
               std::optional<InVector<uint32_t>> light_motion_time_steps,
               std::optional<Matrices> light_motion_transforms, std::optional<PointLightRows> material_shaping,
               std::optional<IesTables> ies_tables, std::optional<InArray<float, 4>> curve_points,
               std::optional<InVector<uint32_t>> curve_segments, std::optional<InVector<uint8_t>> curve_flags,
               std::optional<InVector<uint32_t>> curve_material, std::optional<InArray<float, 7>> media,
               std::optional<InArray<int32_t, 2>> material_media, std::optional<nb::dict> light_links,
               const std::string& light_selection, std::optional<nb::dict> light_rows,
               std::optional<nb::list> grid_media, std::optional<InVector<bool>> material_interface_only) {
                SceneDesc desc = MakeDesc(positions, indices, triangle_material, albedo, emission, two_sided_emission,
                                          sphere_lights, point_lights, distant_lights, dome_radiance, preview_params,
                                          preview_mask, dome_texture, dome_world_to_light, shading_normals,
                                          ies_tables);
                AddExtras(&desc, Extras{uvs, images, image_srgb, texture_table, texture_tiles, material_textures,
                                        prototypes, instance_prototype, instance_transforms, motion_instances,
                                        motion_time_steps, motion_transforms, light_motion_kinds,
                                        light_motion_indices, light_motion_time_steps, light_motion_transforms,
                                        material_shaping, ies_tables, curve_points, curve_segments,
                                        curve_flags, curve_material, light_links});
                AddMedia(&desc, MediaArgs{media, grid_media, material_media, material_interface_only});
                if (light_rows) AddLightRows(&desc, *light_rows);
                if (light_selection == "power") desc.light_selection = SceneDesc::LightSelection::kPower;
                else if (light_selection == "bvh") desc.light_selection = SceneDesc::LightSelection::kBVH;
                else if (light_selection != "auto")
                    throw std::invalid_argument("light_selection must be 'auto', 'power' or 'bvh', not '" +
                                                light_selection + "'");
                nb::gil_scoped_release release;
                new (self) Scene(desc);
            },
            "positions"_a, "indices"_a, "triangle_material"_a, "albedo"_a, "emission"_a, "two_sided_emission"_a,
            "sphere_lights"_a, "point_lights"_a, "distant_lights"_a, "dome_radiance"_a,
            "preview_params"_a = nb::none(), "preview_mask"_a = nb::none(), "dome_texture"_a = nb::none(),
            "dome_world_to_light"_a = nb::none(), "shading_normals"_a = nb::none(), "uvs"_a = nb::none(),
            "images"_a = nb::none(), "image_srgb"_a = nb::none(), "texture_table"_a = nb::none(),
            "texture_tiles"_a = nb::none(), "material_textures"_a = nb::none(), "prototypes"_a = nb::none(),
            "instance_prototype"_a = nb::none(), "instance_transforms"_a = nb::none(),
            "motion_instances"_a = nb::none(), "motion_time_steps"_a = nb::none(), "motion_transforms"_a = nb::none(),
            "light_motion_kinds"_a = nb::none(), "light_motion_indices"_a = nb::none(),
            "light_motion_time_steps"_a = nb::none(), "light_motion_transforms"_a = nb::none(),
            "material_shaping"_a = nb::none(), "ies_tables"_a = nb::none(), "curve_points"_a = nb::none(),
            "curve_segments"_a = nb::none(), "curve_flags"_a = nb::none(), "curve_material"_a = nb::none(),
            "media"_a = nb::none(), "material_media"_a = nb::none(), "light_links"_a = nb::none(),
            "light_selection"_a = "auto", "light_rows"_a = nb::none(), "grid_media"_a = nb::none(),
            "material_interface_only"_a = nb::none(),
            "Builds the BVH. light_rows: {kind name: float32 (lights, columns)} for the kinds light_kinds() "
            "gives columns, the row layout their own files in lights/ state (the first three columns a "
            "position). Rows of the others: sphere_lights (cx, cy, cz, radius, r, g, b radiance); point_lights "
            "(x, y, z, r, g, b intensity W/sr, then optionally the shaping columns of light_shaping.h: "
            "shaped, axis xyz, cutoff, smooth start, focus, focus tint rgb, IES table + 1 (0 none), horizontal "
            "angle 0 axis xyz); distant_lights (dx, dy, dz travel direction, half angle in "
            "radians, r, g, b radiance, or irradiance when the half angle is 0); dome_radiance (r, g, b); "
            "preview_params (specular rgb, metallic, roughness, ior, clearcoat, clearcoat_roughness, opacity, "
            "opacity_threshold, use_specular_workflow, 1 - transmission tint rgb (0 0 0: clear)) for the materials where preview_mask is set: "
            "those are UsdPreviewSurfaces, the others pure Lambertian. dome_texture: float32 (h, w, 3) lat-long "
            "(OpenEXR convention) multiplied by dome_radiance; dome_world_to_light: its 3x3 rotation; "
            "shading_normals: float32 (triangles, 3, 3) world-space corner normals. uvs: float32 (triangles, 3, "
            "2) corner st. images: list of float32 (h, w, channels 1-4) arrays, rows top to bottom, with "
            "image_srgb (bool per image: decode sRGB colour channels). texture_table: float32 (textures, 22): "
            "image index (-1 none), udim (0/1: use texture_tiles row, 100 image indices for tiles 1001..1100), "
            "wrapS, wrapT (0 repeat, 1 clamp, 2 mirror, 3 black), scale[4], bias[4], fallback[4], output (0 r, "
            "1 g, 2 b, 3 a, 4 rgb), UsdTransform2d scale[2], rotation (degrees), translation[2]. "
            "material_textures: int32 (materials, 10) texture per input (diffuseColor, emissiveColor, "
            "specularColor, metallic, roughness, clearcoat, clearcoatRoughness, opacity, ior, normal), -1 none. "
            "prototypes: list of (positions, indices, triangle_material, normals or None, uvs or None[, "
            "motion_positions (T-1, V, 3) or None: a deforming prototype's further time steps]) in "
            "prototype space; instance_prototype uint32 (N,) and instance_transforms float32 (N, 4, 4) (USD "
            "row-vector convention) place them without copying triangles. Transform motion: instance "
            "motion_instances[k] moves through motion_time_steps[k] (2-129) matrices evenly spaced over the "
            "shutter, taken in order from motion_transforms float32 (total steps, 4, 4), interpolated "
            "linearly between them (renderer/core/scene/scene.h). Moving lights: light "
            "light_motion_indices[k] of kind light_motion_kinds[k] (uint8: the kind's position in "
            "light_kinds(); the dome has index 0) moves rigidly through light_motion_time_steps[k] world-space transforms "
            "(light_motion_transforms float32 (total steps, 4, 4), row-vector convention) applied to it as "
            "described above. material_shaping float32 (materials, 14): per material the shaping columns "
            "of a point light: a shaped area light's emission about its emitting normal (shaped 1) or its "
            "axis (2). "
            "ies_tables float32 (tables, 181, 73): IES factors by vertical angle 0..180 (1 degree apart) and "
            "horizontal angle 0..360 (5 degrees apart), named by the shaping columns. Curves (round linear, "
            "world space): curve_points float32 (points, 4) x y z radius; per segment curve_segments uint32 "
            "(its first point; it ends at the next), curve_flags uint8 (1: a segment before it on the same "
            "curve, 2: one after it) and curve_material uint32. Participating media (docs/media.md): media float32 "
            "(N, 7) sigma_a rgb, sigma_s rgb (per unit length), Henyey-Greenstein g; grid_media: list of (density "
            "float32 (nz, ny, nx), world_to_index float32 (3, 4), float32 (7,) sigma_a rgb, sigma_s rgb per unit "
            "density, g), numbered after media; material_media int32 (materials, 2) the medium inside (opposite "
            "the geometric normal) and outside each material, -1 vacuum; material_interface_only bool "
            "(materials,): pure medium interfaces. light_links: a dict of UsdLux light and "
            "shadow links (renderer/core/lights/light_links.h): 'illuminates' and 'shadows' uint8 (links, "
            "groups) flags, 'material_group' uint32 and 'material_light' int32 per material (its link group; "
            "an area light's link, -1 none), 'sphere', 'point', 'distant' int32 per light and 'dome' int32 (1,) "
            "(-1: lights everything).")
        .def_prop_ro("has_motion", &Scene::has_motion)
        .def_prop_ro("has_delta_surfaces", &Scene::has_delta_surfaces)
        .def_prop_ro("has_media", &Scene::has_media)
        .def_prop_ro(
            "kind_without_light_paths",
            [](const Scene& s) -> std::optional<std::string> {
                if (const char* k = s.kind_without_light_paths()) return std::string(k);
                return std::nullopt;
            },
            "The name of a light kind in the scene that cannot start light paths (portal), or None: "
            "integrators with traces_light_paths refuse the scene.")
        .def_prop_ro("num_triangles", &Scene::num_triangles)
        .def_prop_ro("num_curve_segments", &Scene::num_curve_segments)
        .def_prop_ro("num_linked_lights", &Scene::num_linked_lights)
        .def_prop_ro("num_emitters", &Scene::num_emitters)
        .def_prop_ro("uses_light_bvh", &Scene::uses_light_bvh)
        .def_prop_ro("num_instances", &Scene::num_instances)
        .def_prop_ro("num_stored_triangles", &Scene::num_stored_triangles)
        .def_prop_ro("texture_bytes", &Scene::texture_bytes)
        .def_prop_ro("splat_exponent", &Scene::splat_exponent,
                     "splats are fixed point in units of 2^splat_exponent (SPLAT_SCALE / 2^e per unit)");

    m.def(
        "light_kinds",
        [] {
            nb::list kinds;
            for (const LightKindInfo& k : LightKindInfos())
                kinds.append(nb::make_tuple(nb::str(k.name), k.moves, k.row_columns));
            return kinds;
        },
        "The core's light kinds as (name, can move rigidly, row columns) in LightKind order: a moving "
        "light's light_motion_kinds entry is its kind's position here; a kind with row columns > 0 is "
        "handed to Scene in light_rows[name].");

    m.def("embree_memory_bytes", &EmbreeMemoryBytes,
          "Bytes Embree holds right now (BVHs and geometry buffers), from its device memory monitor.");

    nb::class_<Camera>(m, "Camera")
        .def(
            "__init__",
            [](Camera* self, std::array<float, 3> origin, std::array<float, 3> right, std::array<float, 3> up,
               std::array<float, 3> forward, float tan_half_width, float tan_half_height, uint32_t width,
               uint32_t height, float lens_radius, float focal_distance, float near, float far, float shift_x,
               float shift_y, bool orthographic, std::optional<CameraPoses> motion) {
                if (width == 0 || height == 0) throw std::invalid_argument("image size must be positive");
                if (!(lens_radius >= 0.f) || !std::isfinite(lens_radius) || !(focal_distance > 0.f) ||
                    !std::isfinite(focal_distance))
                    throw std::invalid_argument("lens radius must be >= 0 and focus distance > 0 (both finite)");
                if (!(near >= 0.f) || !(far > near))
                    throw std::invalid_argument("clipping range needs 0 <= near < far");
                if (!(tan_half_width > 0.f) || !(tan_half_height > 0.f) || !std::isfinite(tan_half_width) ||
                    !std::isfinite(tan_half_height))
                    throw std::invalid_argument("camera field of view must be finite and positive");
                if (!std::isfinite(shift_x) || !std::isfinite(shift_y))
                    throw std::invalid_argument("camera window shift must be finite");
                if (orthographic && lens_radius > 0.f)
                    throw std::invalid_argument("an orthographic camera has no lens (lens_radius must be 0)");
                new (self) Camera{ToVec3(origin), Normalize(ToVec3(right)), Normalize(ToVec3(up)),
                                  Normalize(ToVec3(forward)), tan_half_width, tan_half_height, width, height,
                                  lens_radius, focal_distance, near, far, shift_x, shift_y,
                                  orthographic ? Projection::kOrthographic : Projection::kPerspective};
                if (motion) {
                    const size_t steps = motion->shape(0);
                    if (steps < 2 || steps > 129)
                        throw std::invalid_argument("camera motion needs 2 to 129 poses, not " + std::to_string(steps));
                    auto poses = std::make_shared<std::vector<CameraPose>>(steps);
                    for (size_t k = 0; k < steps; ++k) {
                        float v[12];
                        for (int j = 0; j < 12; ++j) {
                            v[j] = (*motion)(k, j);
                            if (!std::isfinite(v[j])) throw std::invalid_argument("camera motion poses must be finite");
                        }
                        const Vec3 forward = Normalize(Vec3(v[9], v[10], v[11])), right = Normalize(Vec3(v[3], v[4], v[5]));
                        (*poses)[k] = {Vec3(v[0], v[1], v[2]), right, Cross(right, forward), forward};
                    }
                    self->motion = std::move(poses);
                }
            },
            "origin"_a, "right"_a, "up"_a, "forward"_a, "tan_half_width"_a, "tan_half_height"_a, "width"_a,
            "height"_a, "lens_radius"_a = 0.f, "focal_distance"_a = 1.f, "near"_a = 0.f,
            "far"_a = std::numeric_limits<float>::infinity(), "shift_x"_a = 0.f, "shift_y"_a = 0.f,
            "orthographic"_a = false, "motion"_a = nb::none(),
            "A pinhole, or a thin lens of radius lens_radius focused at focal_distance; primary rays see "
            "depths in [near, far]. The image window spans +-tan_half_width/height around (shift_x, "
            "shift_y): at distance 1 for perspective, in scene units on the film plane for orthographic "
            "(parallel rays along forward; renderer/core/scene/camera.h). motion: float32 (T, 12), "
            "2 <= T <= 129 poses (origin, right, up, forward) evenly spaced over the shutter (a moving "
            "camera; each camera sample sees it at its own instant).")
        .def_prop_ro("moves", &Camera::Moves)
        .def_ro("width", &Camera::width)
        .def_ro("height", &Camera::height);

    m.attr("AOV_NAMES") = nb::make_tuple("albedo", "normal", "depth", "spp");

    m.def(
        "integrators",
        [] {
            nb::list out;
            for (const IntegratorInfo& info : RegisteredIntegrators()) {
                nb::dict d, params;
                d["name"] = std::string(info.name);
                d["description"] = std::string(info.description);
                d["splats"] = info.splats;
                d["scene_passes"] = info.scene_passes;
                d["stop_per_tile"] = info.stop_per_tile;
                d["complete"] = info.complete;
                d["delta_caustics"] = info.delta_caustics;
                d["handles_media"] = info.handles_media;
                d["handles_grid_media"] = info.handles_grid_media;
                d["shades_curves"] = info.shades_curves;
                d["honours_light_links"] = info.honours_light_links;
                using Pilot = IntegratorInfo::PilotCandidate;
                d["pilot_candidate"] = info.pilot_candidate == Pilot::kAlways ? "always"
                                       : info.pilot_candidate == Pilot::kMirrorsOrGlassWithNoiseTarget
                                           ? "mirrors_or_glass_with_noise_target"
                                           : "never";
                d["merging_alpha"] = info.merging_alpha;
                d["view_independent_product"] = info.view_independent_product;
                d["traces_light_paths"] = info.traces_light_paths;
                d["estimates"] = std::string(info.estimates);
                nb::list blind;
                for (const PathExclusion& x : info.blind_to) {
                    nb::dict entry;
                    entry["paths"] = std::string(x.paths);
                    entry["reason"] = std::string(x.reason);
                    blind.append(entry);
                }
                d["blind_to"] = blind;
                if (!info.iteration_cap.param.empty()) {
                    nb::dict cap;
                    cap["param"] = std::string(info.iteration_cap.param);
                    cap["per_batch"] = info.iteration_cap.per_batch;
                    cap["max_param"] = std::string(info.iteration_cap.max_param);
                    cap["max_per_iteration"] = info.iteration_cap.max_per_iteration;
                    d["iteration_cap"] = cap;
                } else {
                    d["iteration_cap"] = nb::none();
                }
                for (const IntegratorParam& p : info.params) params[std::string(p.name).c_str()] = std::string(p.description);
                d["params"] = params;
                out.append(d);
            }
            return out;
        },
        "The registered integrators in registry order: dicts of name, description, the capabilities "
        "(splats, scene_passes, stop_per_tile, complete, delta_caustics, shades_curves, iteration_cap, "
        "pilot_candidate, merging_alpha, view_independent_product, traces_light_paths; "
        "integrators/integrator.h), what a pixel estimates, the light-path classes it is blind to (dicts of "
        "paths and reason; classes from PATH_CLASSES) and "
        "params (setting name -> description).");
    {
        nb::list classes;
        for (std::string_view c : kPathClasses) classes.append(std::string(c));
        m.attr("PATH_CLASSES") = classes;
    }
    m.def(
        "auto_integrator", [](bool scene_has_delta_caustics) { return std::string(AutoIntegrator(scene_has_delta_caustics)); },
        "scene_has_delta_caustics"_a,
        "The `auto` rule: the first complete integrator, among those that find delta-light caustics if "
        "the scene has them.");

    m.def(
        "check_integrator",
        [](const Scene& scene, const std::string& integrator, int max_depth,
           const std::map<std::string, float>& integrator_params) {
            if (max_depth < 0) throw std::invalid_argument("max_depth must be >= 0");
            Integrator::Create(integrator, {max_depth, integrator_params}, scene);
        },
        "scene"_a, "integrator"_a, "max_depth"_a, "integrator_params"_a,
        "Makes the integrator as a render would and discards it: ValueError, in the integrator's own "
        "words, for a setting value it refuses (before any work is done).");

    m.def(
        "render_tile",
        [](const Scene& scene, const Camera& camera, uint32_t x0, uint32_t y0, uint32_t width, uint32_t height,
           uint32_t spp, uint32_t seed, int max_depth, int threads, uint32_t sample_start, bool with_variance,
           const std::string& integrator, std::optional<SplatArray> splats, const std::string& sampler,
           const std::vector<std::string>& aovs, const std::map<std::string, float>& integrator_params,
           std::optional<nb::bytes> scene_product, std::optional<BatchSplatArray> batch_splats,
           std::optional<BatchRgbArray> batch_rgb, std::optional<std::array<uint32_t, 4>> camera_window) {
            RenderOptions options{.spp = spp, .seed = seed, .max_depth = max_depth, .threads = threads,
                                  .sample_start = sample_start, .integrator = integrator,
                                  .integrator_params = integrator_params, .sampler = ParseSampler(sampler)};
            if (scene_product) options.scene_product.assign(scene_product->c_str(), scene_product->size());
            if (const auto& w = camera_window) options.camera_window = TileRect{(*w)[0], (*w)[1], (*w)[2], (*w)[3]};
            int64_t* splat_data = nullptr;
            if (splats) {
                if (splats->shape(0) != camera.height || splats->shape(1) != camera.width)
                    throw std::invalid_argument("splats must have shape (height, width, 3) of the full image");
                splat_data = splats->data();
            }
            VarianceBatches batches;
            if (batch_splats || batch_rgb) {
                if (!batch_splats || !batch_rgb)
                    throw std::invalid_argument("variance batches need both batch_splats and batch_rgb");
                batches.count = uint32_t(batch_splats->shape(0));
                if (batch_splats->shape(1) != camera.height || batch_splats->shape(2) != camera.width)
                    throw std::invalid_argument("batch_splats must have shape (batches, height, width, 3) of the "
                                                "full image");
                if (batch_rgb->shape(0) != batches.count || batch_rgb->shape(1) != height ||
                    batch_rgb->shape(2) != width)
                    throw std::invalid_argument("batch_rgb must have shape (batches, tile height, tile width, 3)");
                batches.splats = batch_splats->data();
                batches.rgb = batch_rgb->data();
            }
            const size_t n = size_t(width) * height;
            auto pixels = std::make_unique<float[]>(n * 4);
            std::unique_ptr<float[]> variance;
            if (with_variance) variance = std::make_unique<float[]>(n * 3);
            std::unique_ptr<float[]> albedo, normal, depth, samples;
            AOVBuffers aov;
            for (const std::string& name : aovs) {
                if (name == "albedo") {
                    if (!albedo) albedo = std::make_unique<float[]>(n * 3);
                    aov.albedo = albedo.get();
                } else if (name == "normal") {
                    if (!normal) normal = std::make_unique<float[]>(n * 3);
                    aov.normal = normal.get();
                } else if (name == "depth") {
                    if (!depth) depth = std::make_unique<float[]>(n);
                    aov.depth = depth.get();
                } else if (name == "spp") {
                    if (!samples) samples = std::make_unique<float[]>(n);
                    aov.samples = samples.get();
                } else {
                    throw std::invalid_argument("unknown AOV '" + name + "' (known: albedo, normal, depth, spp)");
                }
            }
            RenderStats stats;
            {
                nb::gil_scoped_release release;
                stats = RenderTile(scene, camera, options, TileRect{x0, y0, width, height}, pixels.get(),
                                   variance.get(), splat_data, aov, batches);
            }
            nb::dict info;
            info["samples"] = stats.samples;
            info["nonfinite_samples"] = stats.nonfinite_samples;
            info["first_nonfinite"] = nb::make_tuple(stats.first_nonfinite_pixel_x, stats.first_nonfinite_pixel_y,
                                                     stats.first_nonfinite_sample);
            info["light_paths"] = stats.light_paths;
            info["rejected_splats"] = stats.rejected_splats;
            info["closest_rays"] = stats.closest_rays;
            info["shadow_rays"] = stats.shadow_rays;
            if (with_variance) info["variance"] = ToNumpy(std::move(variance), {height, width, 3});
            if (albedo) info["albedo"] = ToNumpy(std::move(albedo), {height, width, 3});
            if (normal) info["normal"] = ToNumpy(std::move(normal), {height, width, 3});
            if (depth) info["depth"] = ToNumpy(std::move(depth), {height, width});
            if (samples) info["spp"] = ToNumpy(std::move(samples), {height, width});
            return nb::make_tuple(ToNumpy(std::move(pixels), {height, width, 4}), info);
        },
        "scene"_a, "camera"_a, "x0"_a, "y0"_a, "width"_a, "height"_a, "spp"_a, "seed"_a = 0, "max_depth"_a = 64,
        "threads"_a = 0, "sample_start"_a = 0, "with_variance"_a = false, "integrator"_a = "path",
        "splats"_a = nb::none(), "sampler"_a = "sobol", "aovs"_a = std::vector<std::string>{},
        "integrator_params"_a = std::map<std::string, float>{}, "scene_product"_a = nb::none(),
        "batch_splats"_a = nb::none(), "batch_rgb"_a = nb::none(), "camera_window"_a = nb::none(),
        "Renders samples [sample_start, sample_start + spp) of a tile; returns (rgba float32 [h, w, 4] mean, "
        "stats dict). With with_variance, stats['variance'] is float32 [h, w, 3]: the per-channel sample "
        "variance. integrator: a name from integrators(), integrator_params its extra settings; one that "
        "splats adds its camera connections to `splats`, an int64 "
        "(height, width, 3) full-frame fixed-point buffer (scale 2^24) owned by the caller. sampler: 'sobol' "
        "(padded Owen-scrambled Sobol, default) or 'independent'. aovs: names from AOV_NAMES; each adds "
        "stats[name] (albedo, normal float32 [h, w, 3]; depth, spp float32 [h, w]; see render.h). "
        "stats['closest_rays'] / stats['shadow_rays']: Embree queries the integrator made. batch_splats "
        "(int64 (K, height, width, 3)) and batch_rgb (float32 (K, h, w, 3)): a splatting "
        "integrator's K variance batches made in the same pass (render.h VarianceBatches); batch k's "
        "splats are added to batch_splats[k] as well as to `splats`. camera_window (x0, y0, w, h): a crop "
        "(render.h RenderOptions::camera_window).");

    m.def(
        "scene_pass",
        [](const Scene& scene, const std::string& integrator, uint32_t iteration, uint32_t seed, int max_depth,
           int threads, const std::map<std::string, float>& integrator_params) {
            RenderOptions options{.seed = seed, .max_depth = max_depth, .threads = threads,
                                  .integrator = integrator, .integrator_params = integrator_params};
            std::string product;
            {
                nb::gil_scoped_release release;
                product = RunScenePass(scene, options, iteration);
            }
            return nb::bytes(product.data(), product.size());
        },
        "scene"_a, "integrator"_a, "iteration"_a, "seed"_a = 0, "max_depth"_a = 64, "threads"_a = 0,
        "integrator_params"_a = std::map<std::string, float>{},
        "The scene-wide pass of `iteration` of an integrator with scene_passes: its product (bytes), a pure "
        "function of (scene, integrator, integrator_params, seed, iteration), handed to every tile of that "
        "iteration as render_tile(..., scene_product=...).");

    m.def(
        "trace_rays",
        [](const Scene& scene, nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu> origins,
           nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu> directions,
           nb::ndarray<const float, nb::shape<-1>, nb::c_contig, nb::device::cpu> t_far, bool occluded,
           int threads, const std::string& interface, bool coherent) {
            const size_t n = origins.shape(0);
            if (directions.shape(0) != n || t_far.shape(0) != n)
                throw std::invalid_argument("origins, directions and t_far need one row per ray");
            if (interface != "single" && interface != "packet8" && interface != "stream")
                throw std::invalid_argument("interface must be 'single', 'packet8' or 'stream'");
            const float* o = origins.data();
            const float* d = directions.data();
            const float* tf = t_far.data();
            RTCScene rtc = scene.embree_scene();
            std::atomic<uint64_t> hits{0};
            double seconds = 0.0;
            auto ray_at = [&](size_t i) {
                return RTCRay{o[3 * i], o[3 * i + 1], o[3 * i + 2], 0.f, d[3 * i], d[3 * i + 1], d[3 * i + 2], 0.f,
                              tf[i], 0xFFFFFFFFu, 0, 0};
            };
            {
                nb::gil_scoped_release release;
                tbb::task_arena arena(threads > 0 ? threads : tbb::this_task_arena::max_concurrency());
                const auto start = std::chrono::steady_clock::now();
                arena.execute([&] {
                    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 256), [&](const tbb::blocked_range<size_t>& r) {
                        const unsigned int saved = _mm_getcsr();
                        _mm_setcsr(saved | 0x8040u);
                        uint64_t local_hits = 0;
                        RTCIntersectContext context;
                        rtcInitIntersectContext(&context);
                        context.flags = coherent ? RTC_INTERSECT_CONTEXT_FLAG_COHERENT
                                                 : RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT;
                        if (interface == "single") {
                            for (size_t i = r.begin(); i != r.end(); ++i) {
                                if (occluded) {
                                    RTCRay ray = ray_at(i);
                                    rtcOccluded1(rtc, &context, &ray);
                                    local_hits += ray.tfar < 0.f;
                                } else {
                                    RTCRayHit rh{ray_at(i), {}};
                                    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
                                    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
                                    rtcIntersect1(rtc, &context, &rh);
                                    local_hits += rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
                                }
                            }
                        } else if (interface == "packet8") {
                            // Consecutive rays, 8 at a time, in Embree's SoA layout.
                            for (size_t i = r.begin(); i < r.end(); i += 8) {
                                alignas(32) int valid[8];
                                alignas(32) RTCRayHit8 rh;
                                for (int k = 0; k < 8; ++k) {
                                    const bool on = i + k < r.end();
                                    valid[k] = on ? -1 : 0;
                                    const RTCRay ray = ray_at(on ? i + k : i);
                                    rh.ray.org_x[k] = ray.org_x, rh.ray.org_y[k] = ray.org_y, rh.ray.org_z[k] = ray.org_z;
                                    rh.ray.dir_x[k] = ray.dir_x, rh.ray.dir_y[k] = ray.dir_y, rh.ray.dir_z[k] = ray.dir_z;
                                    rh.ray.tnear[k] = 0.f, rh.ray.tfar[k] = ray.tfar, rh.ray.time[k] = 0.f;
                                    rh.ray.mask[k] = 0xFFFFFFFFu, rh.ray.id[k] = 0, rh.ray.flags[k] = 0;
                                    rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
                                    rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
                                }
                                if (occluded) {
                                    rtcOccluded8(valid, rtc, &context, &rh.ray);
                                    for (int k = 0; k < 8; ++k) local_hits += valid[k] && rh.ray.tfar[k] < 0.f;
                                } else {
                                    rtcIntersect8(valid, rtc, &context, &rh);
                                    for (int k = 0; k < 8; ++k)
                                        local_hits += valid[k] && rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID;
                                }
                            }
                        } else {
                            // The whole range as one stream (rtcIntersect1M / rtcOccluded1M).
                            std::vector<RTCRayHit> stream(r.size());
                            for (size_t i = r.begin(); i != r.end(); ++i) {
                                RTCRayHit& rh = stream[i - r.begin()];
                                rh.ray = ray_at(i);
                                rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
                                rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
                            }
                            if (occluded) {
                                rtcOccluded1M(rtc, &context, &stream[0].ray, unsigned(stream.size()), sizeof(RTCRayHit));
                                for (const RTCRayHit& rh : stream) local_hits += rh.ray.tfar < 0.f;
                            } else {
                                rtcIntersect1M(rtc, &context, stream.data(), unsigned(stream.size()), sizeof(RTCRayHit));
                                for (const RTCRayHit& rh : stream) local_hits += rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
                            }
                        }
                        hits.fetch_add(local_hits, std::memory_order_relaxed);
                        _mm_setcsr(saved);
                    });
                });
                seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
            }
            return nb::make_tuple(hits.load(), seconds);
        },
        "scene"_a, "origins"_a, "directions"_a, "t_far"_a, "occluded"_a = false, "threads"_a = 0,
        "interface"_a = "single", "coherent"_a = false,
        "Raw Embree: casts the given rays (float32 (n, 3) origins and unit directions, (n,) t_far, t_near 0) "
        "through the scene's BVH on `threads` threads, doing nothing else, by `interface`: 'single' "
        "(rtcIntersect1 / rtcOccluded1 per ray), 'packet8' (consecutive rays 8 at a time, rtcIntersect8 / "
        "rtcOccluded8) or 'stream' (each range of 256 rays as one rtcIntersect1M / rtcOccluded1M call); "
        "`coherent` sets Embree's COHERENT context hint instead of INCOHERENT. Returns (hits, seconds): "
        "the ceiling the renderer's rays/s is measured against.");
}
