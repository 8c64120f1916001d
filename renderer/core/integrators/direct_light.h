// Next event estimation at one surface point, shared by the integrators that shade with
// light sampling (path, local, whitted).
#pragma once

#include "bsdf.h"
#include "sampler.h"
#include "sampling.h"
#include "scene.h"

namespace tessera {

// One light sample at a surface: Le f |cos| / pdf through the BSDF's non-delta lobes, with
// a shadow ray. With `mis`, weighted by the power heuristic against BSDF sampling of the
// same direction (delta lights always get weight 1). The light is chosen by
// Scene::SampleLight at (hit.p, hit.ns): a caller weighing BSDF-sampled emitter hits asks
// Scene::LightPmf at the same point and normal. Inline, as it could be when it shared
// the path tracer's file: it runs at every vertex of the hot loops.
// `Shading` is BSDF, or one of its kinds when the caller knows which (PathIntegrator).
template <typename Shading>
inline Color SampleDirectLight(const Scene& scene, const SurfaceHit& hit, const Shading& bsdf, const Frame& frame,
                               Vec3 wo, PixelSampler& sampler, bool mis) {
    float pmf = 0.f;
    uint32_t light = 0;
    const bool chosen = scene.SampleLight(sampler.Get1D(), hit.p, hit.ns, &light, &pmf);
    const Vec2 u = sampler.Get2D();  // drawn either way: the dimensions after it stay put
    if (!chosen) return Color(0.f);
    LightSample ls;
    if (!scene.SampleEmitter(light, hit.p, u, &ls)) return Color(0.f);
    const float light_pdf = pmf * ls.pdf;
    if (!(light_pdf > 0.f)) return Color(0.f);
    const Vec3 wo_local = frame.ToLocal(wo), wi_local = frame.ToLocal(ls.wi);
    if (!SidesAgree(wo, ls.wi, hit.ng, wo_local, wi_local)) return Color(0.f);
    const Color f = bsdf.f(wo_local, wi_local) * std::abs(wi_local.z);
    if (IsBlack(f) || !scene.Unoccluded(hit.p, hit.p_error, hit.ng, ls))
        return Color(0.f);
    // A delta light cannot be hit by BSDF sampling: light sampling takes it all.
    const float w = (mis && !ls.is_delta) ? PowerHeuristic(light_pdf, bsdf.PDF(wo_local, wi_local)) : 1.f;
    return f * ls.radiance * (w / light_pdf);
}

}  // namespace tessera
