// The camera side of the photon-merging integrators (`photon`, `sppm`): a camera ray
// followed through delta lobes (mirrors, smooth glass) to the surfaces where the photon
// map is read, the "visible points" of (stochastic) progressive photon mapping.
#pragma once

#include <optional>

#include "bsdf.h"
#include "integrator.h"
#include "sampler.h"
#include "scene.h"

namespace tessera {

// Walks E S* from the camera: adds every emitter (and light at infinity) the chain sees,
// and calls shade(hit, bsdf, frame, wo, beta) -> Color at each vertex with a non-delta
// lobe, where the caller estimates the light reflected by those lobes. A BSDF that also
// has a delta lobe is sampled once more and the walk continues only if the sample took the
// delta lobe, so each lobe's light is counted once (the others are shade's). Returns the
// pixel sample.
template <typename Shade>
PathSample TraceVisiblePoints(const Scene& scene, const CameraSample& cs, PixelSampler& sampler, int max_depth,
                              Shade&& shade) {
    PathSample result;
    Color L(0.f), beta(1.f);
    float eta_scale = 1.f;  // refraction's radiance scaling, hidden from roulette
    Ray ray = cs.ray;
    for (int depth = 0;; ++depth) {
        SurfaceHit hit;
        if (!(depth == 0 ? scene.Intersect(ray, &hit, cs.t_min, cs.t_max) : scene.Intersect(ray, &hit))) {
            scene.ForEachEnvironmentLight(ray.o, ray.d, [&](uint32_t, Color Le, float) { L += beta * Le; });
            break;
        }
        if (depth == 0) result.alpha = 1.f;
        const Vec3 wo = -ray.d;
        if (int32_t e = scene.EmitterAt(hit); e != Scene::kNoEmitter) L += beta * scene.Emitted(e, hit, wo);
        if (depth >= max_depth) break;
        const BSDF bsdf = scene.BSDFAt(hit, TransportMode::Radiance);
        if (bsdf.Flags() == kBSDFUnset) break;
        const Frame frame = Frame::FromZ(hit.ns);
        if (bsdf.IsNonSpecular()) L += beta * shade(hit, bsdf, frame, wo, beta);
        if (!bsdf.HasDelta()) break;
        const Vec3 wo_local = frame.ToLocal(wo);
        const float uc = sampler.Get1D();
        const std::optional<BSDFSample> bs = bsdf.Sample_f(wo_local, uc, sampler.Get2D());
        if (!bs || !bs->is_specular || !(bs->pdf > 0.f) || IsBlack(bs->f)) break;
        const Vec3 wi = Normalize(frame.FromLocal(bs->wi));
        if (!SidesAgree(wo, wi, hit.ng, wo_local, bs->wi)) break;
        beta *= bs->f * (std::abs(bs->wi.z) / bs->pdf);
        if (bs->is_transmission) eta_scale *= bs->eta * bs->eta;
        ray = {OffsetRayOrigin(hit.p, hit.p_error, hit.ng, wi), wi};
        // A chain of delta lobes loses energy at every vertex (Fresnel, absorption): stop
        // it by Russian roulette once it has gone deep, as the path tracer does.
        if (depth >= 2) {
            const float q = std::min(1.f, MaxComponent(beta) * eta_scale);
            if (sampler.Get1D() >= q) break;
            beta = beta / q;
        }
    }
    result.radiance = L;
    return result;
}

}  // namespace tessera
