// The Scene's participating-media arguments (docs/media.md) as the binding receives them,
// and their decoding into a SceneDesc: apart from scene_arrays.h, whose tables describe
// surfaces and lights.
#pragma once

#include <optional>

#include "scene_arrays.h"

namespace tessera::binding {

// A density grid, (nz, ny, nx), x fastest (density_grid.h).
using DensityArray = nb::ndarray<const float, nb::ndim<3>, nb::c_contig, nb::device::cpu>;

struct MediaArgs {
    // Homogeneous media: rows sigma_a rgb, sigma_s rgb, g.
    std::optional<InArray<float, 7>> media;
    // Grid media, numbered after the homogeneous ones: tuples (density (nz, ny, nx),
    // world_to_index (3, 4), (sigma_a rgb, sigma_s rgb, g) per unit density).
    std::optional<nb::list> grid_media;
    // Per material: (inside, outside) medium, -1 for vacuum; and whether it is a pure interface.
    std::optional<InArray<int32_t, 2>> material_media;
    std::optional<InVector<bool>> material_interface_only;
};

void AddMedia(SceneDesc* d, const MediaArgs& a);

}  // namespace tessera::binding
