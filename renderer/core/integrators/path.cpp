#include "path.h"

#include <cmath>
#include <stdexcept>
#include <type_traits>

#include "bsdf.h"
#include "bsdf_step.h"
#include "direct_light.h"
#include "path_lanes.h"
#include "sampling.h"

namespace tessera {

const IntegratorInfo& PathIntegrator::Info() {
    static const IntegratorInfo info{
        .name = "path",
        .description = "path tracing: next event estimation, MIS with BSDF sampling, Russian roulette",
        .complete = true,
        .handles_media = true,
        .handles_grid_media = true,
        .honours_light_links = true,
        .params = {{"rr_depth", "vertex index (0 = the first hit) from which Russian roulette may end a path "
                                "(default 2; 5 reaches an error sooner in closed diffuse scenes)"},
                   {"lanes", "lane width of the lane-group kernel for all-Lambertian still scenes: 0 (the scalar "
                             "kernel, the default: the lane kernel measured 1.09x its time), 1, 4, 8, or -1 for the "
                             "CPU's (8 with AVX2, else 4); the same image to the bit either way; other scenes "
                             "always take the scalar kernel"}},
        .pilot_candidate = IntegratorInfo::PilotCandidate::kAlways,
    };
    return info;
}

IntegratorEntry PathIntegratorEntry() {
    return {PathIntegrator::Info, [](const IntegratorSettings& s, const Scene& scene) -> std::unique_ptr<Integrator> {
                const float rr = s.Param("rr_depth", float(PathIntegrator::kDefaultRouletteDepth));
                if (!(rr >= 0.f && rr <= 1e6f && rr == std::floor(rr)))
                    throw std::invalid_argument("path rr_depth must be a whole number >= 0 (the vertex index from "
                                                "which Russian roulette may end a path)");
                // The lane kernel stays opt-in until it beats the scalar one: with its shading
                // still scalar per lane it measured 1.09x the scalar kernel's time on the
                // exported Cornell box (docs/benchmarks/simd-kernel.md).
                float lanes = s.Param("lanes", 0.f);
                if (lanes == -1.f) lanes = float(DefaultLaneWidth());
                if (!(lanes == 0.f || lanes == 1.f || lanes == 4.f || lanes == 8.f))
                    throw std::invalid_argument("path lanes must be 0 (the scalar kernel), 1, 4, 8 or -1 (the CPU's "
                                                "lane width)");
                // Chosen here, once per render of the scene: no per-sample cost.
                return std::make_unique<PathIntegrator>(s.max_depth, int(rr),
                                                        LaneKernelApplies(scene) ? int(lanes) : 0);
            }};
}

PathSample PathIntegrator::Li(const Scene& scene, Ray ray, PixelSampler& sampler, float t_min, float t_max) const {
    if (kFullFeatures && scene.has_media()) return TraceMedia(scene, ray, sampler, t_min, t_max);
    // Links: through BSDF, which renders an all-Lambertian scene to the same bits.
    if (kFullFeatures && scene.has_light_links()) return Trace<BSDF, true>(scene, ray, sampler, t_min, t_max);
    return scene.all_lambertian() ? Trace<DiffuseBSDF, false>(scene, ray, sampler, t_min, t_max)
                                  : Trace<BSDF, false>(scene, ray, sampler, t_min, t_max);
}

void PathIntegrator::SampleBatch(const Scene& scene, BatchSample* samples, PathSample* out, size_t n) const {
    TraceLanes(scene, lanes_, max_depth_, roulette_depth_, samples, out, n);
}

template <typename Shading, bool kLinks>
PathSample PathIntegrator::Trace(const Scene& scene, Ray ray, PixelSampler& sampler, float t_min, float t_max) const {
    PathSample result;
    Color L(0.f), beta(1.f);
    float bsdf_pdf = 0.f;         // solid-angle pdf of the direction that produced `ray`
    bool specular_bounce = false; // ...and whether it came from a delta lobe (no MIS then)
    float eta_scale = 1.f;        // product of eta^2 over refractions, hidden from roulette
    Vec3 prev_p, prev_n;          // the vertex `ray` left from and its shading normal (light pmf under MIS)
    uint32_t prev_group = Scene::kNoLinkGroup;  // ...and its link group (light links: which lights reach it)
    const LightSampler& lights = scene.light_sampler();
    constexpr bool links = kLinks;
    // The weight of emission from `light` reached by BSDF sampling from the previous vertex,
    // given the light-sampling density there. Linking: a light that does not illuminate the
    // previous surface adds nothing, and one whose shadow link excludes some surface is
    // left to light sampling alone (direct_light.h), as a delta light is. The camera ray
    // (depth 0) sees every light. Light sampling chose by the previous vertex's group, so
    // its density there is the group's (Scene::LightPmf with the group).
    auto bsdf_hit_weight = [&](int depth, uint32_t light, auto light_pdf) -> float {
        if (links && depth > 0 && !scene.Illuminates(light, prev_group)) return 0.f;
        if (depth == 0 || specular_bounce) return 1.f;
        if (links && scene.ExcludesShadows(light)) return 0.f;
        return PowerHeuristic(bsdf_pdf, light_pdf());
    };

    for (int depth = 0;; ++depth) {
        SurfaceHit hit;
        if (!(depth == 0 ? scene.Intersect(ray, &hit, t_min, t_max) : scene.Intersect(ray, &hit))) {
            // Escaped: lights at infinity (dome, distant cones), weighted like emitters.
            scene.ForEachEnvironmentLight(ray.o, ray.d, [&](uint32_t light, Color Le, float pdf) {
                const float w = bsdf_hit_weight(depth, light, [&] { return scene.LightPmf(prev_p, prev_n, light, prev_group) * pdf; });
                L += beta * Le * w;
            });
            break;
        }
        if (depth == 0) result.alpha = 1.f;
        const Vec3 wo = -ray.d;

        // Emission reached by BSDF sampling, weighted against light sampling of the same
        // point. The camera ray and delta bounces have no competing strategy.
        if (int32_t e = scene.EmitterAt(hit); e != Scene::kNoEmitter) {
            Color Le = scene.Emitted(e, hit, wo);
            if (!IsBlack(Le)) {
                const float w = bsdf_hit_weight(depth, uint32_t(e), [&] {
                    return scene.LightPmf(prev_p, prev_n, uint32_t(e), prev_group) * scene.EmitterPdf(e, prev_p, hit);
                });
                L += beta * Le * w;
            }
        }
        if (depth >= max_depth_) break;

        const Shading bsdf = [&] {
            if constexpr (std::is_same_v<Shading, DiffuseBSDF>) return DiffuseBSDF(scene.LambertianAlbedoAt(hit));
            else return scene.BSDFAt(hit, TransportMode::Radiance);
        }();
        if (bsdf.Flags() == kBSDFUnset) break;
        // The frame keeps the wound side: dielectrics tell inside from outside by it.
        const Frame frame = Frame::FromZ(hit.ns);
        const Vec3 wo_local = frame.ToLocal(wo);

        // Next event estimation: one light chosen by power, one point on it.
        if (!lights.empty() && bsdf.IsNonSpecular())
            L += beta * SampleDirectLight<Shading, kLinks>(scene, hit, bsdf, frame, wo, sampler, /*mis=*/true);

        // BSDF sampling continues the path.
        const std::optional<BSDFStep> step = SampleBSDFStep(bsdf, frame, wo, wo_local, hit.ng, sampler, beta);
        if (!step) break;
        const BSDFSample* bs = &step->sample;
        const Vec3 wi = step->wi;
        bsdf_pdf = bs->pdf;
        specular_bounce = bs->is_specular;
        if (bs->is_transmission) eta_scale *= bs->eta * bs->eta;
        prev_p = hit.p;
        prev_n = hit.ns;
        if (links) prev_group = scene.LinkGroupAt(hit);
        ray = {OffsetRayOrigin(hit.p, hit.p_error, hit.ng, wi), wi};

        // Russian roulette from vertex roulette_depth_ on: survive with probability equal
        // to the throughput's largest channel (refraction's radiance scaling removed), then
        // divide, keeping the estimator unbiased.
        if (depth >= roulette_depth_) {
            float q = std::min(1.f, MaxComponent(beta) * eta_scale);
            if (sampler.Get1D() >= q) break;
            beta = beta / q;
        }
    }
    result.radiance = L;
    return result;
}

}  // namespace tessera
