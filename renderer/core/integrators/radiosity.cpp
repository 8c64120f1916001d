// Radiosity (Goral et al. 1984) solved by progressive refinement (Cohen et al. 1988): the
// lecture's method 5, L D* E. The scene pass meshes the scene and solves for the
// radiosity of every element (renderer/core/radiosity/); the solution does not depend on
// the iteration, so every pass's product is the same bytes and the farm stores it once.
// A tile casts one primary ray per pixel sample and reads the radiosity interpolated at
// the point it hits: L = Le + B_reflected / pi. Every surface is treated as Lambertian
// with its diffuse reflectance (a mirror or clear glass is black; docs/integrators.md).
#include <stdexcept>

#include "integrator.h"
#include "radiosity_product.h"

namespace tessera {

namespace {

constexpr float kInvPi = 0.318309886183790671538f;

class RadiosityIntegrator final : public Integrator {
public:
    RadiosityIntegrator(const IntegratorSettings& s, const Scene& scene)
        : settings_(RadiositySettingsFrom(s, scene, "radiosity")) {
        const bool interpolate = RadiosityInterpolates(s, "radiosity", true);
        if (!s.scene_product.empty())
            lookup_ = std::make_unique<RadiosityLookup>(scene, settings_.element_size, s.scene_product, interpolate,
                                                        "radiosity");
    }

    static const IntegratorInfo& Info() {
        static const IntegratorInfo info{
            .name = "radiosity",
            .description = "progressive refinement radiosity (Southwell shooting, diffuse albedos; scene-wide "
                           "solve, one primary ray per sample)",
            .scene_passes = true,
            // Every tile reads the same solution; the image advances together.
            .stop_per_tile = false,
            .shades_curves = false,
            .params = RadiosityParams(),
            .blind_to = {{"L S+ E", "every surface is treated as Lambertian: smooth mirrors and glass (delta "
                                    "lobes) reflect and transmit nothing"}},
            .view_independent_product = true,
        };
        return info;
    }
    const IntegratorInfo& info() const override { return Info(); }

    std::string RunScenePass(const Scene& scene, uint32_t seed, uint32_t, int threads) const override {
        RadiositySettings s = settings_;
        s.seed = seed;
        s.threads = threads;
        return SolveRadiosityProduct(scene, s);
    }

    PathSample Sample(const Scene& scene, const Camera&, const CameraSample& cs, PixelSampler&, SplatFilm&,
                      IntegratorCounters*) const override {
        PathSample result;
        SurfaceHit hit;
        if (!scene.Intersect(cs.ray, &hit, cs.t_min, cs.t_max)) return result;
        result.alpha = 1.f;
        const Vec3 wo = -cs.ray.d;
        if (int32_t e = scene.EmitterAt(hit); e != Scene::kNoEmitter) result.radiance += scene.Emitted(e, hit, wo);
        Color reflected, direct;
        if (lookup_->Reflected(hit, wo, &reflected, &direct)) result.radiance += reflected * kInvPi;
        return result;
    }

private:
    RadiositySettings settings_;
    std::unique_ptr<RadiosityLookup> lookup_;
};

}  // namespace

IntegratorEntry RadiosityIntegratorEntry() {
    return {RadiosityIntegrator::Info, [](const IntegratorSettings& s, const Scene& scene) -> std::unique_ptr<Integrator> {
                return std::make_unique<RadiosityIntegrator>(s, scene);
            }};
}

}  // namespace tessera
