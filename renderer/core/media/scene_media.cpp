// The scene's participating media (media/medium.h): validation, and the queries the
// volumetric path tracer makes through medium boundaries.
#include <stdexcept>
#include <string>

#include "scene.h"

namespace tessera {

namespace {
// A path crossing more boundaries than this in one segment is caught in a degenerate mesh
// (coincident sheets); it is ended rather than looped on.
constexpr int kMaxBoundaryCrossings = 256;
}  // namespace

void Scene::BuildMedia(const SceneDesc& desc) {
    media_ = desc.media;
    for (size_t i = 0; i < media_.size(); ++i)
        if (!media_[i].Valid())
            throw std::invalid_argument("medium " + std::to_string(i) +
                                        ": sigma_a and sigma_s must be finite and >= 0, and |g| < 1");
    grid_media_ = desc.grid_media;
    for (size_t i = 0; i < grid_media_.size(); ++i) {
        const std::string what = "grid medium " + std::to_string(i) + ": ";
        if (!grid_media_[i].Valid())
            throw std::invalid_argument(what + "needs a density grid, sigma_a and sigma_s finite and >= 0, and |g| < 1");
        if (grid_media_[i].grid->block_max.empty()) {
            try {
                grid_media_[i].grid->BuildBlocks();
            } catch (const std::invalid_argument& e) {
                throw std::invalid_argument(what + e.what());
            }
        }
    }
    const int64_t num_media = int64_t(media_.size() + grid_media_.size());
    for (size_t m = 0; m < materials_.size(); ++m) {
        const Material& mat = materials_[m];
        const std::string what = "material " + std::to_string(m) + ": ";
        for (int32_t k : {mat.media.inside, mat.media.outside})
            if (k < -1 || k >= num_media)
                throw std::invalid_argument(what + "refers to medium " + std::to_string(k) + " of " +
                                            std::to_string(num_media));
        if (mat.interface_only && !mat.media.is_boundary())
            throw std::invalid_argument(what + "is a pure medium interface but names no medium on either side");
        if (mat.interface_only && (mat.preview || !IsBlack(mat.emission) || !IsBlack(mat.albedo)))
            throw std::invalid_argument(what + "is a pure medium interface: it may have no albedo, emission or "
                                               "UsdPreviewSurface");
        has_media_ = has_media_ || mat.media.is_boundary();
    }
    if (!curve_material_.empty())
        for (uint32_t m : curve_material_)
            if (materials_[m].media.is_boundary())
                throw std::invalid_argument("material " + std::to_string(m) +
                                            " bounds a medium and is bound to curves: only closed meshes bound media");
}

const MediumInterface& Scene::MediumInterfaceAt(const SurfaceHit& hit) const {
    static const MediumInterface kNone;
    const int64_t mi = MaterialIndexAt(hit);
    return mi >= 0 ? materials_[size_t(mi)].media : kNone;
}

bool Scene::IsInterfaceOnly(const SurfaceHit& hit) const {
    const int64_t mi = MaterialIndexAt(hit);
    return mi >= 0 && materials_[size_t(mi)].interface_only;
}

int32_t Scene::MediumAt(Vec3 p) const {
    if (!has_media_) return -1;
    // The first boundary a ray from p meets tells which side of it p is on. The direction
    // is fixed and off every axis, so axis-aligned meshes are not met edge-on.
    const Vec3 dir = Normalize(Vec3(0.5773f, 0.5917f, 0.5628f));
    Ray ray{p, dir};
    for (int crossing = 0; crossing < kMaxBoundaryCrossings; ++crossing) {
        SurfaceHit hit;
        if (!Intersect(ray, &hit)) return -1;
        const MediumInterface& mi = MediumInterfaceAt(hit);
        if (mi.is_boundary()) return Dot(dir, hit.ng) > 0.f ? mi.inside : mi.outside;
        ray.o = OffsetRayOrigin(hit.p, hit.p_error, hit.ng, dir);
    }
    return -1;
}

namespace {
// Transmittance of medium i over [0, len] of the ray (o, dir): Beer-Lambert, or residual
// ratio tracking in a grid (seeded by the ray: the same shadow ray, the same estimate).
Color SegmentTransmittance(const Scene& scene, int32_t i, Vec3 o, Vec3 dir, float len) {
    if (const GridMedium* g = scene.grid_medium(i)) {
        TrackingRng rng(TrackingSeed(o, dir, len));
        return EstimateTransmittance(*g, g->sigma_t(), o, dir, 0.f, len, rng);
    }
    return scene.medium(i).Transmittance(len);
}
}  // namespace

Color Scene::Transmittance(Vec3 p, float p_error, Vec3 ng, int32_t medium, const LightSample& ls) const {
    const bool infinite = std::isinf(ls.distance);
    Vec3 from = OffsetRayOrigin(p, p_error, ng, ls.wi);
    const Vec3 to = infinite ? Vec3(0.f) : OffsetRayOrigin(ls.p, ls.p_error, ls.n, from - ls.p);
    Color tr(1.f);
    for (int crossing = 0; crossing < kMaxBoundaryCrossings; ++crossing) {
        Vec3 dir = ls.wi;
        float len = std::numeric_limits<float>::infinity();
        if (!infinite) {
            const Vec3 d = to - from;
            len = Length(d);
            if (!(len > 0.f)) return Color(0.f);
            dir = d / len;
        }
        SurfaceHit hit;
        // As Unoccluded: both ends sit off their surfaces; the shortening absorbs Embree's rounding.
        if (!Intersect({from, dir}, &hit, 0.f, infinite ? len : len * (1.f - kShadowEpsilon))) {
            if (medium >= 0) tr *= SegmentTransmittance(*this, medium, from, dir, len);
            return tr;
        }
        if (!IsInterfaceOnly(hit)) return Color(0.f);
        if (medium >= 0) tr *= SegmentTransmittance(*this, medium, from, dir, hit.t);
        if (IsBlack(tr)) return tr;
        medium = MediumInterfaceAt(hit).After(hit.ng, dir, medium);
        from = OffsetRayOrigin(hit.p, hit.p_error, hit.ng, dir);
    }
    return Color(0.f);
}

}  // namespace tessera
