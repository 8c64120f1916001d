#include "path_integrator.h"

#include "sampling.h"

namespace tessera {

PathSample PathIntegrator::Li(const Scene& scene, Ray ray, PixelSampler& sampler) const {
    PathSample result;
    Color L(0.f), beta(1.f);
    float bsdf_pdf = 0.f;  // solid-angle pdf of the direction that produced `ray`
    Vec3 prev_p;           // the vertex `ray` left from (for the light pdf under MIS)
    const LightSampler& lights = scene.light_sampler();

    for (int depth = 0;; ++depth) {
        SurfaceHit hit;
        if (!scene.Intersect(ray, &hit)) {
            // Escaped: lights at infinity (dome, distant cones), weighted like emitters.
            scene.ForEachEnvironmentLight(ray.d, [&](uint32_t light, Color Le, float pdf) {
                float w = depth == 0 ? 1.f : PowerHeuristic(bsdf_pdf, lights.Pmf(light) * pdf);
                L += beta * Le * w;
            });
            break;
        }
        if (depth == 0) result.alpha = 1.f;
        const Vec3 wo = -ray.d;

        // Emission reached by BSDF sampling, weighted against light sampling of the same
        // point. The camera ray (depth 0) has no competing strategy.
        if (int32_t e = scene.EmitterAt(hit); e != Scene::kNoEmitter) {
            Color Le = scene.Emitted(e, hit, wo);
            if (!IsBlack(Le)) {
                float w = 1.f;
                if (depth > 0) w = PowerHeuristic(bsdf_pdf, lights.Pmf(uint32_t(e)) * scene.EmitterPdf(e, prev_p, hit));
                L += beta * Le * w;
            }
        }
        if (depth >= max_depth_) break;

        const Material& m = scene.MaterialAt(hit);
        if (IsBlack(m.albedo)) break;
        // Lambertian surfaces reflect on both sides: shade with the normal facing wo.
        const Vec3 n = Dot(hit.ng, wo) >= 0.f ? hit.ng : -hit.ng;
        const Color f = m.albedo * kInvPi;

        // Next event estimation: one emitter chosen by power, one point on it.
        if (!lights.empty()) {
            float pmf = 0.f;
            uint32_t light = lights.Sample(sampler.Get1D(), &pmf);
            Vec2 u = sampler.Get2D();
            LightSample ls;
            if (scene.SampleEmitter(light, hit.p, u, &ls)) {
                float cos_i = Dot(n, ls.wi);
                float light_pdf = pmf * ls.pdf;
                if (cos_i > 0.f && light_pdf > 0.f &&
                    !scene.Occluded(OffsetRayOrigin(hit.p, n, ls.wi), ls.wi, ls.distance * (1.f - 1e-4f))) {
                    // A delta light cannot be hit by BSDF sampling: light sampling takes it all.
                    float w = ls.is_delta ? 1.f : PowerHeuristic(light_pdf, CosineHemispherePdf(cos_i));
                    L += beta * f * ls.radiance * (cos_i * w / light_pdf);
                }
            }
        }

        // BSDF sampling: cosine-weighted, so f cos / pdf = albedo.
        Vec3 local = SampleCosineHemisphere(sampler.Get2D());
        bsdf_pdf = CosineHemispherePdf(local.z);
        if (!(bsdf_pdf > 0.f)) break;
        Vec3 wi = Frame::FromZ(n).FromLocal(local);
        beta *= m.albedo;
        prev_p = hit.p;
        ray = {OffsetRayOrigin(hit.p, n, wi), Normalize(wi)};

        // Russian roulette from the third vertex on: survive with probability equal to the
        // throughput's largest channel, then divide, keeping the estimator unbiased.
        if (depth >= 2) {
            float q = std::min(1.f, MaxComponent(beta));
            if (sampler.Get1D() >= q) break;
            beta = beta / q;
        }
    }
    result.radiance = L;
    return result;
}

}  // namespace tessera
