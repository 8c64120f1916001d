// Decoding of the Scene's media arguments into a SceneDesc (media_arrays.h).
#include "media_arrays.h"

#include <memory>
#include <string>

namespace tessera::binding {

void AddMedia(SceneDesc* d, const MediaArgs& a) {
    if (a.media)
        for (size_t i = 0; i < a.media->shape(0); ++i) {
            const auto& m = *a.media;
            d->media.push_back({Vec3(m(i, 0), m(i, 1), m(i, 2)), Vec3(m(i, 3), m(i, 4), m(i, 5)), m(i, 6)});
        }
    if (a.grid_media)
        for (size_t k = 0; k < a.grid_media->size(); ++k) {
            nb::tuple item = nb::cast<nb::tuple>((*a.grid_media)[k]);
            const std::string what = "grid_media[" + std::to_string(k) + "]: ";
            if (item.size() != 3)
                throw std::invalid_argument(what + "a grid medium is (density, world_to_index, coefficients)");
            auto density = nb::cast<DensityArray>(item[0]);
            auto w2i = nb::cast<nb::ndarray<const float, nb::shape<3, 4>, nb::c_contig, nb::device::cpu>>(item[1]);
            auto co = nb::cast<nb::ndarray<const float, nb::shape<7>, nb::c_contig, nb::device::cpu>>(item[2]);
            auto grid = std::make_shared<DensityGrid>();
            grid->nz = int(density.shape(0));
            grid->ny = int(density.shape(1));
            grid->nx = int(density.shape(2));
            grid->density.assign(density.data(), density.data() + density.size());
            for (int i = 0; i < 12; ++i) grid->world_to_index[i] = w2i.data()[i];
            d->grid_media.push_back({Vec3(co(0), co(1), co(2)), Vec3(co(3), co(4), co(5)), co(6), std::move(grid)});
        }
    const size_t n_mat = d->materials.size();
    if (a.material_media) {
        if (a.material_media->shape(0) != n_mat)
            throw std::invalid_argument("material_media needs one row (inside, outside) per material");
        for (size_t m = 0; m < n_mat; ++m)
            d->materials[m].media = {(*a.material_media)(m, 0), (*a.material_media)(m, 1)};
    }
    if (a.material_interface_only) {
        if (a.material_interface_only->shape(0) != n_mat)
            throw std::invalid_argument("material_interface_only needs one entry per material");
        for (size_t m = 0; m < n_mat; ++m) d->materials[m].interface_only = (*a.material_interface_only)(m);
    }
}

}  // namespace tessera::binding
