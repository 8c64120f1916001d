// Decoding of the Scene's arrays into a SceneDesc (scene_arrays.h).
#include "scene_arrays.h"

#include <nanobind/stl/optional.h>
#include <nanobind/stl/string.h>

#include <cmath>
#include <string>
#include <vector>

namespace tessera::binding {

namespace {

template <typename Column>
LightShaping ShapingFromColumns(Column col, size_t first, const std::optional<IesTables>& tables) {
    LightShaping s;
    if (col(first) == 0.f) return s;
    s.enabled = true;
    s.about_axis = col(first) == 2.f;
    s.axis = Normalize(Vec3(col(first + 1), col(first + 2), col(first + 3)));
    s.cutoff = col(first + 4);
    s.smooth_start = col(first + 5);
    s.focus = col(first + 6);
    s.focus_tint = Vec3(col(first + 7), col(first + 8), col(first + 9));
    const Vec3 zero(col(first + 11), col(first + 12), col(first + 13));
    if (Length(zero) > 0.f) s.azimuth_zero = Normalize(zero);
    if (const float table = col(first + 10); table != 0.f) {
        const size_t n = tables ? tables->shape(0) : 0;
        if (!(table >= 1.f && table <= float(n) && table == std::floor(table)))
            throw std::invalid_argument("shaping names IES table " + std::to_string(table - 1.f) + " of " +
                                        std::to_string(n));
        const float* t = tables->data() + (size_t(table) - 1) * kIesSamples * kIesAzimuths;
        s.ies.assign(t, t + kIesSamples * kIesAzimuths);
    }
    return s;
}

WrapMode ToWrap(float v) {
    switch (int(v)) {
        case 1: return WrapMode::kClamp;
        case 2: return WrapMode::kMirror;
        case 3: return WrapMode::kBlack;
        default: return WrapMode::kRepeat;
    }
}

using FlagTable = nb::ndarray<const uint8_t, nb::shape<-1, -1>, nb::c_contig, nb::device::cpu>;

template <typename T>
std::vector<T> VectorEntry(const nb::dict& links, const char* key) {
    if (!links.contains(key)) return {};
    auto v = nb::cast<InVector<T>>(links[key]);
    return std::vector<T>(v.data(), v.data() + v.shape(0));
}

void AddLightLinks(SceneDesc* d, const nb::dict& links) {
    if (!links.contains("illuminates") || !links.contains("shadows"))
        throw std::invalid_argument("light_links needs 'illuminates' and 'shadows' tables");
    auto illuminates = nb::cast<FlagTable>(links["illuminates"]);
    auto shadows = nb::cast<FlagTable>(links["shadows"]);
    if (shadows.shape(0) != illuminates.shape(0) || shadows.shape(1) != illuminates.shape(1))
        throw std::invalid_argument("light_links: 'illuminates' and 'shadows' must have one shape");
    d->light_links = LightLinkTable(uint32_t(illuminates.shape(1)),
                                    std::vector<uint8_t>(illuminates.data(), illuminates.data() + illuminates.size()),
                                    std::vector<uint8_t>(shadows.data(), shadows.data() + shadows.size()));
    const std::vector<uint32_t> groups = VectorEntry<uint32_t>(links, "material_group");
    const std::vector<int32_t> lights = VectorEntry<int32_t>(links, "material_light");
    if ((!groups.empty() && groups.size() != d->materials.size()) ||
        (!lights.empty() && lights.size() != d->materials.size()))
        throw std::invalid_argument("light_links: material_group and material_light need one entry per material");
    for (size_t m = 0; m < groups.size(); ++m) d->materials[m].link_group = groups[m];
    for (size_t m = 0; m < lights.size(); ++m) d->materials[m].light_link = lights[m];
    d->sphere_light_link = VectorEntry<int32_t>(links, "sphere");
    d->point_light_link = VectorEntry<int32_t>(links, "point");
    d->distant_light_link = VectorEntry<int32_t>(links, "distant");
    const std::vector<int32_t> dome = VectorEntry<int32_t>(links, "dome");
    if (dome.size() > 1) throw std::invalid_argument("light_links: 'dome' holds one link");
    d->dome_light_link = dome.empty() ? -1 : dome[0];
}

}  // namespace

void AddLightRows(SceneDesc* d, const nb::dict& rows) {
    const std::vector<LightKindInfo> infos = LightKindInfos();
    d->light_rows.assign(infos.size(), {});
    for (auto [key, value] : rows) {
        const std::string name = nb::cast<std::string>(key);
        size_t k = 0;
        while (k < infos.size() && name != infos[k].name) ++k;
        if (k == infos.size()) throw std::invalid_argument("light_rows: the core has no light kind '" + name + "'");
        if (infos[k].row_columns == 0)
            throw std::invalid_argument("light_rows: " + name + " lights are not handed over in rows");
        auto a = nb::cast<nb::ndarray<const float, nb::ndim<2>, nb::c_contig, nb::device::cpu>>(value);
        if (a.shape(0) > 0 && a.shape(1) != infos[k].row_columns)
            throw std::invalid_argument("light_rows['" + name + "'] needs " + std::to_string(infos[k].row_columns) +
                                        " columns, not " + std::to_string(a.shape(1)));
        d->light_rows[k].assign(a.data(), a.data() + a.size());
    }
}

void AddExtras(SceneDesc* d, const Extras& x) {
    const size_t n_tri = d->indices.size() / 3;
    if (x.uvs) {
        if (x.uvs->shape(0) != n_tri) throw std::invalid_argument("uvs must have shape (triangles, 3, 2)");
        d->uvs.assign(x.uvs->data(), x.uvs->data() + x.uvs->size());
    }
    if (x.images) {
        const size_t n = x.images->size();
        if (!x.image_srgb || x.image_srgb->shape(0) != n)
            throw std::invalid_argument("image_srgb needs one flag per image");
        for (size_t i = 0; i < n; ++i) {
            AnyImage a = nb::cast<AnyImage>((*x.images)[i]);
            Image im;
            im.height = uint32_t(a.shape(0));
            im.width = uint32_t(a.shape(1));
            im.channels = uint32_t(a.shape(2));
            im.texels.assign(a.data(), a.data() + a.size());
            im.srgb = (*x.image_srgb)(i);
            d->images.push_back(std::move(im));
        }
    }
    if (x.texture_table) {
        const auto& t = *x.texture_table;
        const size_t n = t.shape(0);
        if (x.texture_tiles && x.texture_tiles->shape(0) != n)
            throw std::invalid_argument("texture_tiles needs one row per texture");
        for (size_t k = 0; k < n; ++k) {
            TextureDesc td;
            td.image = int32_t(t(k, 0));
            if (t(k, 1) != 0.f) {
                if (!x.texture_tiles) throw std::invalid_argument("a UDIM texture needs texture_tiles");
                td.udim_tiles.assign(&(*x.texture_tiles)(k, 0), &(*x.texture_tiles)(k, 0) + 100);
            }
            td.wrap_s = ToWrap(t(k, 2));
            td.wrap_t = ToWrap(t(k, 3));
            for (int c = 0; c < 4; ++c) {
                td.scale[c] = t(k, 4 + c);
                td.bias[c] = t(k, 8 + c);
                td.fallback[c] = t(k, 12 + c);
            }
            const int out = int(t(k, 16));
            if (out < 0 || out > 4) throw std::invalid_argument("texture output must be 0..4 (r, g, b, a, rgb)");
            td.output = TextureOutput(out);
            td.st_scale[0] = t(k, 17);
            td.st_scale[1] = t(k, 18);
            td.st_rotation_degrees = t(k, 19);
            td.st_translation[0] = t(k, 20);
            td.st_translation[1] = t(k, 21);
            d->textures.push_back(std::move(td));
        }
    }
    if (x.material_textures) {
        if (x.material_textures->shape(0) != d->materials.size())
            throw std::invalid_argument("material_textures needs one row per material");
        for (size_t m = 0; m < d->materials.size(); ++m)
            for (int s = 0; s < kNumTextureSlots; ++s) d->materials[m].textures[s] = (*x.material_textures)(m, s);
    }
    if (x.prototypes) {
        for (size_t k = 0; k < x.prototypes->size(); ++k) {
            nb::tuple item = nb::cast<nb::tuple>((*x.prototypes)[k]);
            if (item.size() != 5 && item.size() != 6)
                throw std::invalid_argument(
                    "a prototype is (positions, indices, triangle_material, normals, uvs[, motion_positions])");
            MeshDesc mesh;
            auto pos = nb::cast<InArray<float, 3>>(item[0]);
            auto idx = nb::cast<InArray<uint32_t, 3>>(item[1]);
            auto mat = nb::cast<InVector<uint32_t>>(item[2]);
            mesh.positions.assign(pos.data(), pos.data() + pos.size());
            mesh.indices.assign(idx.data(), idx.data() + idx.size());
            mesh.triangle_material.assign(mat.data(), mat.data() + mat.size());
            if (!item[3].is_none()) {
                auto n = nb::cast<CornerNormals>(item[3]);
                mesh.shading_normals.assign(n.data(), n.data() + n.size());
            }
            if (!item[4].is_none()) {
                auto uv = nb::cast<CornerUVs>(item[4]);
                mesh.uvs.assign(uv.data(), uv.data() + uv.size());
            }
            if (item.size() == 6 && !item[5].is_none()) {
                // (T - 1, V, 3): the vertices at time steps 1 .. T-1 (MeshDesc::motion_positions).
                auto steps = nb::cast<nb::ndarray<const float, nb::ndim<3>, nb::c_contig, nb::device::cpu>>(item[5]);
                if (steps.shape(2) != 3 || steps.shape(1) != pos.shape(0))
                    throw std::invalid_argument("motion_positions must be (time steps - 1, vertices, 3)");
                mesh.motion_positions.assign(steps.data(), steps.data() + steps.size());
            }
            d->prototypes.push_back(std::move(mesh));
        }
    }
    if (x.instance_prototype) {
        const size_t n = x.instance_prototype->shape(0);
        if (!x.instance_transforms || x.instance_transforms->shape(0) != n)
            throw std::invalid_argument("instance_transforms needs one 4x4 matrix per instance");
        d->instance_prototype.assign(x.instance_prototype->data(), x.instance_prototype->data() + n);
        d->instance_transforms.resize(12 * n);
        // USD matrices act on row vectors (p' = p M): transpose into row-major 3x4.
        for (size_t i = 0; i < n; ++i)
            for (int r = 0; r < 3; ++r)
                for (int c = 0; c < 4; ++c) d->instance_transforms[12 * i + 4 * r + c] = (*x.instance_transforms)(i, c, r);
    }
    if (x.motion_instances) {
        if (!x.motion_time_steps || !x.motion_transforms)
            throw std::invalid_argument("motion_instances needs motion_time_steps and motion_transforms");
        d->motion_instances.assign(x.motion_instances->data(), x.motion_instances->data() + x.motion_instances->shape(0));
        d->motion_time_steps.assign(x.motion_time_steps->data(),
                                    x.motion_time_steps->data() + x.motion_time_steps->shape(0));
        const size_t n = x.motion_transforms->shape(0);
        d->motion_transforms.resize(12 * n);
        for (size_t i = 0; i < n; ++i)
            for (int r = 0; r < 3; ++r)
                for (int c = 0; c < 4; ++c) d->motion_transforms[12 * i + 4 * r + c] = (*x.motion_transforms)(i, c, r);
    }
    if (x.material_shaping) {
        // One row per material: the shaping of a shaped area light's emission (shaped? 0: none).
        if (x.material_shaping->shape(0) != d->materials.size() || x.material_shaping->shape(1) != kShapingColumns)
            throw std::invalid_argument("material_shaping needs one row of " + std::to_string(kShapingColumns) +
                                        " shaping columns per material");
        for (size_t m = 0; m < d->materials.size(); ++m) {
            LightShaping s =
                ShapingFromColumns([&](size_t c) { return (*x.material_shaping)(m, c); }, 0, x.ies_tables);
            if (!s.enabled) continue;
            d->materials[m].emission_shaping = int32_t(d->emission_shapings.size());
            d->emission_shapings.push_back(std::move(s));
        }
    }
    if (x.curve_points || x.curve_segments || x.curve_flags || x.curve_material) {
        if (!x.curve_points || !x.curve_segments || !x.curve_flags || !x.curve_material)
            throw std::invalid_argument("curves need curve_points, curve_segments, curve_flags and curve_material");
        d->curve_points.assign(x.curve_points->data(), x.curve_points->data() + x.curve_points->size());
        d->curve_segments.assign(x.curve_segments->data(), x.curve_segments->data() + x.curve_segments->size());
        d->curve_flags.assign(x.curve_flags->data(), x.curve_flags->data() + x.curve_flags->size());
        d->curve_material.assign(x.curve_material->data(), x.curve_material->data() + x.curve_material->size());
    }
    if (x.light_links) AddLightLinks(d, *x.light_links);
    if (x.light_motion_kinds) {
        if (!x.light_motion_indices || !x.light_motion_time_steps || !x.light_motion_transforms)
            throw std::invalid_argument(
                "light_motion_kinds needs light_motion_indices, light_motion_time_steps and light_motion_transforms");
        for (size_t k = 0; k < x.light_motion_kinds->shape(0); ++k) {
            const uint8_t kind = (*x.light_motion_kinds)(k);
            if (kind >= LightKinds::kCount || !LightKindInfos()[kind].moves)
                throw std::invalid_argument("light_motion_kinds: " + MovingKindNames() + ", not " +
                                            std::to_string(kind));
            d->light_motion_kinds.push_back(LightKind(kind));
        }
        d->light_motion_indices.assign(x.light_motion_indices->data(),
                                       x.light_motion_indices->data() + x.light_motion_indices->shape(0));
        d->light_motion_time_steps.assign(x.light_motion_time_steps->data(),
                                          x.light_motion_time_steps->data() + x.light_motion_time_steps->shape(0));
        const size_t n = x.light_motion_transforms->shape(0);
        d->light_motion_transforms.resize(12 * n);
        for (size_t i = 0; i < n; ++i)
            for (int r = 0; r < 3; ++r)
                for (int c = 0; c < 4; ++c)
                    d->light_motion_transforms[12 * i + 4 * r + c] = (*x.light_motion_transforms)(i, c, r);
    }
}

SceneDesc MakeDesc(InArray<float, 3> positions, InArray<uint32_t, 3> indices, InVector<uint32_t> triangle_material,
                   InArray<float, 3> albedo, InArray<float, 3> emission, InVector<bool> two_sided_emission,
                   InArray<float, 7> sphere_lights, PointLightRows point_lights, InArray<float, 7> distant_lights,
                   std::array<float, 3> dome_radiance, std::optional<InArray<float, 14>> preview_params,
                   std::optional<InVector<bool>> preview_mask, std::optional<DomeImage> dome_texture,
                   std::optional<InArray<float, 3>> dome_world_to_light,
                   std::optional<CornerNormals> shading_normals, const std::optional<IesTables>& ies_tables) {
    SceneDesc d;
    d.positions.assign(positions.data(), positions.data() + positions.size());
    d.indices.assign(indices.data(), indices.data() + indices.size());
    d.triangle_material.assign(triangle_material.data(), triangle_material.data() + triangle_material.size());
    const size_t n_mat = albedo.shape(0);
    if (emission.shape(0) != n_mat || two_sided_emission.shape(0) != n_mat)
        throw std::invalid_argument("albedo, emission and two_sided_emission need one row per material");
    for (size_t m = 0; m < n_mat; ++m)
        d.materials.push_back({Vec3(albedo(m, 0), albedo(m, 1), albedo(m, 2)),
                               Vec3(emission(m, 0), emission(m, 1), emission(m, 2)), two_sided_emission(m)});
    for (size_t s = 0; s < sphere_lights.shape(0); ++s)
        d.sphere_lights.push_back({Vec3(sphere_lights(s, 0), sphere_lights(s, 1), sphere_lights(s, 2)),
                                   sphere_lights(s, 3),
                                   Vec3(sphere_lights(s, 4), sphere_lights(s, 5), sphere_lights(s, 6))});
    if (point_lights.shape(1) != 6 && point_lights.shape(1) != kShapedPointLightColumns)
        throw std::invalid_argument("point_lights need 6 columns, or " +
                                    std::to_string(kShapedPointLightColumns) + " with shaping");
    for (size_t i = 0; i < point_lights.shape(0); ++i) {
        auto col = [&](size_t c) { return point_lights(i, c); };
        PointLight light{Vec3(col(0), col(1), col(2)), Vec3(col(3), col(4), col(5))};
        if (point_lights.shape(1) == kShapedPointLightColumns) light.shaping = ShapingFromColumns(col, 6, ies_tables);
        d.point_lights.push_back(light);
    }
    for (size_t i = 0; i < distant_lights.shape(0); ++i)
        d.distant_lights.push_back({Vec3(distant_lights(i, 0), distant_lights(i, 1), distant_lights(i, 2)),
                                    distant_lights(i, 3),
                                    Vec3(distant_lights(i, 4), distant_lights(i, 5), distant_lights(i, 6))});
    d.dome_radiance = ToVec3(dome_radiance);
    if (shading_normals) {
        if (shading_normals->shape(0) != d.indices.size() / 3)
            throw std::invalid_argument("shading_normals must have shape (triangles, 3, 3)");
        d.shading_normals.assign(shading_normals->data(), shading_normals->data() + shading_normals->size());
    }
    if (dome_texture) {
        d.dome_height = uint32_t(dome_texture->shape(0));
        d.dome_width = uint32_t(dome_texture->shape(1));
        d.dome_rgb.assign(dome_texture->data(), dome_texture->data() + dome_texture->size());
    }
    if (dome_world_to_light) {
        if (dome_world_to_light->shape(0) != 3) throw std::invalid_argument("dome_world_to_light must be 3x3");
        for (int i = 0; i < 9; ++i) d.dome_world_to_light[i] = dome_world_to_light->data()[i];
    }
    if (preview_params && preview_mask) {
        if (preview_params->shape(0) != n_mat || preview_mask->shape(0) != n_mat)
            throw std::invalid_argument("preview_params and preview_mask need one row per material");
        for (size_t m = 0; m < n_mat; ++m) {
            if (!(*preview_mask)(m)) continue;
            const auto& q = *preview_params;
            MaterialParams p;
            p.diffuse_color = d.materials[m].albedo;
            p.emissive_color = d.materials[m].emission;
            p.specular_color = Vec3(q(m, 0), q(m, 1), q(m, 2));
            p.metallic = q(m, 3);
            p.roughness = q(m, 4);
            p.ior = q(m, 5);
            p.clearcoat = q(m, 6);
            p.clearcoat_roughness = q(m, 7);
            p.opacity = q(m, 8);
            p.opacity_threshold = q(m, 9);
            p.use_specular_workflow = q(m, 10) != 0.f;
            // Stored as 1 - tint, so that tables written before the column existed (zeros) are clear glass.
            p.transmission_tint = Vec3(1.f - q(m, 11), 1.f - q(m, 12), 1.f - q(m, 13));
            d.materials[m].preview = p;
        }
    }
    return d;
}

}  // namespace tessera::binding
