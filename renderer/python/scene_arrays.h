// The Scene's arrays as the binding receives them (numpy, via nanobind) and their decoding
// into a SceneDesc. Apart from module.cpp, which binds the classes and functions: the
// layout of the tables is one role, the Python interface another.
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <array>
#include <optional>

#include "scene.h"

namespace tessera::binding {

namespace nb = nanobind;

template <typename T, int C>
using InArray = nb::ndarray<const T, nb::shape<-1, C>, nb::c_contig, nb::device::cpu>;
template <typename T>
using InVector = nb::ndarray<const T, nb::shape<-1>, nb::c_contig, nb::device::cpu>;

using CornerNormals = nb::ndarray<const float, nb::shape<-1, 3, 3>, nb::c_contig, nb::device::cpu>;
using CornerUVs = nb::ndarray<const float, nb::shape<-1, 3, 2>, nb::c_contig, nb::device::cpu>;
using AnyImage = nb::ndarray<const float, nb::ndim<3>, nb::c_contig, nb::device::cpu>;
using Matrices = nb::ndarray<const float, nb::shape<-1, 4, 4>, nb::c_contig, nb::device::cpu>;
// Point lights: (x, y, z, r, g, b) rows, or those followed by UsdLux shaping columns
// (kShapingColumns, below).
using PointLightRows = nb::ndarray<const float, nb::shape<-1, -1>, nb::c_contig, nb::device::cpu>;
// IES tables (light_shaping.h): (tables, kIesSamples, kIesAzimuths).
using IesTables = nb::ndarray<const float, nb::shape<-1, kIesSamples, kIesAzimuths>, nb::c_contig, nb::device::cpu>;
using DomeImage = nb::ndarray<const float, nb::shape<-1, -1, 3>, nb::c_contig, nb::device::cpu>;

// The shaping columns of light_shaping.h from column `first` of a row: shaped? (0 no, 1 about
// the emitting normal, 2 about the axis: LightShaping::about_axis), axis xyz,
// cone cutoff and smooth start in radians, focus, focus tint rgb, IES table index + 1 (0:
// none), horizontal angle 0's axis xyz (the light's +X).
constexpr size_t kShapingColumns = 14;
constexpr size_t kShapedPointLightColumns = 6 + kShapingColumns;

// Columns of the texture table (one row per texture), see the Scene docstring.
constexpr size_t kTextureColumns = 22;

// Everything the texture and instancing tables add to a Scene (keyword arguments).
struct Extras {
    std::optional<CornerUVs> uvs;
    std::optional<nb::list> images;
    std::optional<InVector<bool>> image_srgb;
    std::optional<InArray<float, kTextureColumns>> texture_table;
    std::optional<InArray<int32_t, 100>> texture_tiles;
    std::optional<InArray<int32_t, kNumTextureSlots>> material_textures;
    std::optional<nb::list> prototypes;
    std::optional<InVector<uint32_t>> instance_prototype;
    std::optional<Matrices> instance_transforms;
    std::optional<InVector<uint32_t>> motion_instances;
    std::optional<InVector<uint32_t>> motion_time_steps;
    std::optional<Matrices> motion_transforms;
    std::optional<InVector<uint8_t>> light_motion_kinds;
    std::optional<InVector<uint32_t>> light_motion_indices;
    std::optional<InVector<uint32_t>> light_motion_time_steps;
    std::optional<Matrices> light_motion_transforms;
    std::optional<PointLightRows> material_shaping;
    std::optional<IesTables> ies_tables;
    std::optional<InArray<float, 4>> curve_points;
    std::optional<InVector<uint32_t>> curve_segments;
    std::optional<InVector<uint8_t>> curve_flags;
    std::optional<InVector<uint32_t>> curve_material;
    // Light linking (SceneData.light_links): {"illuminates", "shadows": uint8 (links,
    // groups); "material_group": uint32, "material_light": int32 per material; "sphere",
    // "point", "distant": int32 per light; "dome": int32 (1,)}.
    std::optional<nb::dict> light_links;
};

// The lights of the kinds handed over in rows ({kind name: float32 (lights, columns)}):
// the kind's name and column count come from the kind (light_kinds.h), nothing per kind here.
void AddLightRows(SceneDesc* d, const nb::dict& rows);

// Checks the extra tables against the description's triangles and materials and adds them.
void AddExtras(SceneDesc* d, const Extras& x);

// The description from the constructor's required arrays and the few optional ones that
// shape its materials and lights.
SceneDesc MakeDesc(InArray<float, 3> positions, InArray<uint32_t, 3> indices, InVector<uint32_t> triangle_material,
                   InArray<float, 3> albedo, InArray<float, 3> emission, InVector<bool> two_sided_emission,
                   InArray<float, 7> sphere_lights, PointLightRows point_lights, InArray<float, 7> distant_lights,
                   std::array<float, 3> dome_radiance, std::optional<InArray<float, 14>> preview_params,
                   std::optional<InVector<bool>> preview_mask, std::optional<DomeImage> dome_texture,
                   std::optional<InArray<float, 3>> dome_world_to_light,
                   std::optional<CornerNormals> shading_normals, const std::optional<IesTables>& ies_tables);

inline Vec3 ToVec3(const std::array<float, 3>& a) { return {a[0], a[1], a[2]}; }

}  // namespace tessera::binding
