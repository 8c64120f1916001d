#include "whitted.h"

#include "bsdf.h"
#include "direct_light.h"
#include "sampling.h"

namespace tessera {

const IntegratorInfo& WhittedIntegrator::Info() {
    static const IntegratorInfo info{
        .name = "whitted",
        .description = "Whitted ray tracing: direct light everywhere, recursion along ideal mirrors and refraction only",
        .blind_to = {{"L D D+ E", "diffuse surfaces get direct light only: recursion follows ideal mirrors "
                                  "and refraction only"}},
    };
    return info;
}

IntegratorEntry WhittedIntegratorEntry() {
    return {WhittedIntegrator::Info, [](const IntegratorSettings& s, const Scene&) -> std::unique_ptr<Integrator> {
                return std::make_unique<WhittedIntegrator>(s.max_depth);
            }};
}

PathSample WhittedIntegrator::Li(const Scene& scene, Ray ray, PixelSampler& sampler, float t_min, float t_max) const {
    PathSample result;
    Color L(0.f), beta(1.f);
    const LightSampler& lights = scene.light_sampler();
    for (int depth = 0;; ++depth) {
        SurfaceHit hit;
        if (!(depth == 0 ? scene.Intersect(ray, &hit, t_min, t_max) : scene.Intersect(ray, &hit))) {
            // Seen directly or through mirrors only: BSDF sampling never met these lights
            // at a diffuse vertex, so no weighting is needed.
            scene.ForEachEnvironmentLight(ray.o, ray.d, [&](uint32_t, Color Le, float) { L += beta * Le; });
            break;
        }
        if (depth == 0) result.alpha = 1.f;
        const Vec3 wo = -ray.d;
        if (int32_t e = scene.EmitterAt(hit); e != Scene::kNoEmitter) L += beta * scene.Emitted(e, hit, wo);
        if (depth >= max_depth_) break;

        const BSDF bsdf = scene.BSDFAt(hit, TransportMode::Radiance);
        if (bsdf.Flags() == kBSDFUnset) break;
        const Frame frame = Frame::FromZ(hit.ns);
        const Vec3 wo_local = frame.ToLocal(wo);

        // Direct light through the non-delta lobes: light sampling alone (unweighted, as
        // emitters are never reached by BSDF sampling at such a vertex here).
        if (!lights.empty() && bsdf.IsNonSpecular())
            L += beta * SampleDirectLight(scene, hit, bsdf, frame, wo, sampler, /*mis=*/false);

        // Recursion along delta lobes only. Sampling the full BSDF and stopping on a
        // non-delta choice keeps the estimate of the delta part unbiased.
        if (!bsdf.HasDelta()) break;
        const float uc = sampler.Get1D();
        const std::optional<BSDFSample> bs = bsdf.Sample_f(wo_local, uc, sampler.Get2D());
        if (!bs || !bs->is_specular || !(bs->pdf > 0.f) || IsBlack(bs->f)) break;
        const Vec3 wi = Normalize(frame.FromLocal(bs->wi));
        if (!SidesAgree(wo, wi, hit.ng, wo_local, bs->wi)) break;
        beta *= bs->f * (std::abs(bs->wi.z) / bs->pdf);
        ray = {OffsetRayOrigin(hit.p, hit.p_error, hit.ng, wi), wi};
        if (depth >= 4) {  // long mirror chains: roulette keeps them finite without bias
            float q = std::min(1.f, MaxComponent(beta));
            if (sampler.Get1D() >= q) break;
            beta = beta / q;
        }
    }
    result.radiance = L;
    return result;
}

}  // namespace tessera
