// Path tracing with a radiosity final gather (after Wallace, Cohen & Greenberg 1987 and
// Sillion & Puech 1989): the lecture's method 6. The camera path follows delta lobes
// (mirrors, glass) as a path tracer does; at its first non-delta vertex x it adds the
// direct light by next event estimation and samples the BSDF once more. Where that ray
// lands on a non-delta surface y, the light leaving y toward x is read from the radiosity
// solution, B_reflected(y) / pi, and the path ends; across delta surfaces it goes on, and
// counts emission it meets there (NEE at x cannot reach a light through a mirror).
//
// Each path is counted once: light arriving at x straight from an emitter is NEE's alone
// (the gather never adds emission at y), and the solution's reflected radiosity at y
// already holds every longer diffuse path L D+ y. The solution's own direct component is
// never read at x, so nothing of it is counted next to NEE.
#include <stdexcept>

#include "bsdf.h"
#include "bsdf_step.h"
#include "direct_light.h"
#include "integrator.h"
#include "radiosity_product.h"

namespace tessera {

namespace {

constexpr float kInvPi = 0.318309886183790671538f;

class HybridIntegrator final : public Integrator {
public:
    HybridIntegrator(const IntegratorSettings& s, const Scene& scene)
        : max_depth_(s.max_depth), settings_(RadiositySettingsFrom(s, scene, "hybrid")) {
        const bool interpolate = RadiosityInterpolates(s, "hybrid", false);
        if (!s.scene_product.empty())
            lookup_ = std::make_unique<RadiosityLookup>(scene, settings_.element_size, s.scene_product, interpolate,
                                                        "hybrid");
    }

    static const IntegratorInfo& Info() {
        static const IntegratorInfo info{
            .name = "hybrid",
            .description = "path tracing of direct light and specular chains, diffuse interreflection from a "
                           "radiosity final gather (scene-wide solve)",
            .scene_passes = true,
            .stop_per_tile = false,
            .params = RadiosityParams(),
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

    PathSample Sample(const Scene& scene, const Camera&, const CameraSample& cs, PixelSampler& sampler, SplatFilm&,
                      IntegratorCounters*) const override {
        PathSample result;
        Color L(0.f), beta(1.f);
        Ray ray = cs.ray;
        bool gathered = false;  // past x: the next non-delta vertex reads the solution
        bool specular_bounce = false;
        const LightSampler& lights = scene.light_sampler();
        for (int depth = 0;; ++depth) {
            SurfaceHit hit;
            if (!(depth == 0 ? scene.Intersect(ray, &hit, cs.t_min, cs.t_max) : scene.Intersect(ray, &hit))) {
                // Lights at infinity: seen directly or through delta lobes only; after a
                // non-delta scattering they are NEE's.
                if (depth == 0 || specular_bounce)
                    scene.ForEachEnvironmentLight(ray.o, ray.d, [&](uint32_t, Color Le, float) { L += beta * Le; });
                break;
            }
            if (depth == 0) result.alpha = 1.f;
            const Vec3 wo = -ray.d;
            if (depth == 0 || specular_bounce)
                if (int32_t e = scene.EmitterAt(hit); e != Scene::kNoEmitter) L += beta * scene.Emitted(e, hit, wo);
            const BSDF bsdf = scene.BSDFAt(hit, TransportMode::Radiance);
            if (bsdf.Flags() == kBSDFUnset) break;
            if (gathered && bsdf.IsNonSpecular()) {
                Color reflected, direct;
                if (lookup_->Reflected(hit, wo, &reflected, &direct)) L += beta * reflected * kInvPi;
                break;
            }
            if (depth >= max_depth_) break;
            const Frame frame = Frame::FromZ(hit.ns);
            const Vec3 wo_local = frame.ToLocal(wo);
            if (!lights.empty() && bsdf.IsNonSpecular())
                L += beta * SampleDirectLight(scene, hit, bsdf, frame, wo, sampler, /*mis=*/false);
            const std::optional<BSDFStep> step = SampleBSDFStep(bsdf, frame, wo, wo_local, hit.ng, sampler, beta);
            if (!step) break;
            const BSDFSample* bs = &step->sample;
            const Vec3 wi = step->wi;
            specular_bounce = bs->is_specular;
            // A non-delta scattering makes this vertex x: from here the next non-delta
            // surface is read from the solution.
            if (!bs->is_specular) gathered = true;
            ray = {OffsetRayOrigin(hit.p, hit.p_error, hit.ng, wi), wi};
        }
        result.radiance = L;
        return result;
    }

private:
    int max_depth_;
    RadiositySettings settings_;
    std::unique_ptr<RadiosityLookup> lookup_;
};

}  // namespace

IntegratorEntry HybridIntegratorEntry() {
    return {HybridIntegrator::Info, [](const IntegratorSettings& s, const Scene& scene) -> std::unique_ptr<Integrator> {
                return std::make_unique<HybridIntegrator>(s, scene);
            }};
}

}  // namespace tessera
