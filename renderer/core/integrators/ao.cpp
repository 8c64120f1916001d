// Ambient occlusion, the fast look-development preview (as hdEmbree offers): at the first
// surface the camera sees, the fraction of the cosine-weighted hemisphere around the
// shading normal that is open up to `max_distance`:
//     AO(p) = (1/pi) * integral over the hemisphere of V(p, w, max_distance) cos(theta) dw,
// white where nothing is near, black in a crevice. One occlusion ray per pixel sample, its
// direction drawn from the cosine density, so each sample is 0 or 1 and the pixel mean is
// an unbiased estimate. Materials and lights play no part; geometry seen through cutouts
// is skipped as by every integrator. The background (no hit) is black with alpha 0.
#include <cmath>
#include <limits>

#include "integrator.h"
#include "sampling.h"

namespace tessera {

namespace {

// The default reach: a tenth of the diameter of the scene's bounding sphere, so that a
// scene's look does not depend on its units (Scene::scene_radius).
constexpr float kDefaultReachOfDiameter = 0.1f;

class AOIntegrator final : public Integrator {
public:
    explicit AOIntegrator(float max_distance) : max_distance_(max_distance) {}
    static const IntegratorInfo& Info() {
        static const IntegratorInfo info{
            .name = "ao",
            .description = "ambient occlusion: open fraction of the cosine-weighted hemisphere (white = unoccluded)",
            .params = {{"max_distance", "how far an occluder counts, in scene units (default: a tenth of the "
                                        "scene's bounding diameter; inf: any distance)"}},
            .estimates = "ambient occlusion",
        };
        return info;
    }
    const IntegratorInfo& info() const override { return Info(); }

    PathSample Sample(const Scene& scene, const Camera&, const CameraSample& cs, PixelSampler& sampler, SplatFilm&,
                      IntegratorCounters*) const override {
        PathSample result;
        SurfaceHit hit;
        if (!scene.Intersect(cs.ray, &hit, cs.t_min, cs.t_max)) return result;
        result.alpha = 1.f;
        // The hemisphere on the viewer's side of the surface.
        const Vec3 wo = -cs.ray.d;
        const float side = Dot(hit.ng, wo) >= 0.f ? 1.f : -1.f;
        const Vec3 ng = hit.ng * side, ns = hit.ns * side;
        const Vec3 wi = Normalize(Frame::FromZ(ns).FromLocal(SampleCosineHemisphere(sampler.Get2D())));
        // A shading normal can tilt the hemisphere below the geometry: those directions
        // enter the surface itself, which occludes them.
        if (!(Dot(wi, ng) > 0.f)) return result;
        if (!scene.Occluded(OffsetRayOrigin(hit.p, hit.p_error, ng, wi), wi, max_distance_))
            result.radiance = Color(1.f);
        return result;
    }

private:
    float max_distance_;
};

}  // namespace

IntegratorEntry AOIntegratorEntry() {
    return {AOIntegrator::Info, [](const IntegratorSettings& s, const Scene& scene) -> std::unique_ptr<Integrator> {
                const float fallback = kDefaultReachOfDiameter * 2.f * scene.scene_radius();
                const float d = s.Param("max_distance", fallback);
                if (!(d > 0.f))
                    throw std::invalid_argument("ao max_distance must be > 0 (inf: any distance)");
                return std::make_unique<AOIntegrator>(d);
            }};
}

}  // namespace tessera
