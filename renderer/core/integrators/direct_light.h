// Next event estimation at one surface point, shared by the integrators that shade with
// light sampling (path, local, whitted).
#pragma once

#include "bsdf.h"
#include "sampler.h"
#include "sampling.h"
#include "scene.h"

namespace tessera {

// The light sample of SampleDirectLight before its shadow ray: the contribution it makes
// if the segment to the light point is free, and that point. The lane kernel
// (path_lanes.h) casts the shadow rays of a whole lane group after shading it; the
// sampler's dimensions are drawn here, so the shadow ray's outcome cannot shift them.
struct UnshadowedLightSample {
    Color contribution{0.f};
    LightSample ls;
    uint32_t light = 0;             // the emitter sampled (its shadow link decides the ray)
    bool needs_shadow_ray = false;  // false: the contribution is zero whatever the ray says
};
// kLinks: honour light and shadow links (light_links.h). Off, the code is what it was
// before links existed: PathIntegrator instantiates that for scenes without any, so they
// pay nothing for them.
template <typename Shading, bool kLinks = true>
inline UnshadowedLightSample SampleDirectLightUnshadowed(const Scene& scene, const SurfaceHit& hit,
                                                         const Shading& bsdf, const Frame& frame, Vec3 wo,
                                                         PixelSampler& sampler, bool mis) {
    UnshadowedLightSample out;
    float pmf = 0.f;
    uint32_t light = 0;
    // Light links: only the lights that illuminate this surface's link group are chosen.
    const uint32_t group = kLinks && scene.has_light_links() ? scene.LinkGroupAt(hit) : Scene::kNoLinkGroup;
    const bool chosen = scene.SampleLight(sampler.Get1D(), hit.p, hit.ns, &light, &pmf, group);
    const Vec2 u = sampler.Get2D();  // drawn either way: the dimensions after it stay put
    if (!chosen) return out;
    out.light = light;
    if (!scene.SampleEmitter(light, hit.p, u, &out.ls)) return out;
    const float light_pdf = pmf * out.ls.pdf;
    if (!(light_pdf > 0.f)) return out;
    const Vec3 wo_local = frame.ToLocal(wo), wi_local = frame.ToLocal(out.ls.wi);
    if (!SidesAgree(wo, out.ls.wi, hit.ng, wo_local, wi_local)) return out;
    const Color f = bsdf.f(wo_local, wi_local) * std::abs(wi_local.z);
    if (IsBlack(f)) return out;
    // A delta light cannot be hit by BSDF sampling: light sampling takes it all, as it does
    // for a light whose shadow link lets rays through surfaces BSDF sampling stops at.
    const float w = (mis && !out.ls.is_delta && !(kLinks && scene.ExcludesShadows(light)))
                        ? PowerHeuristic(light_pdf, bsdf.PDF(wo_local, wi_local))
                        : 1.f;
    out.contribution = f * out.ls.radiance * (w / light_pdf);
    out.needs_shadow_ray = true;
    return out;
}

// One light sample at a surface: Le f |cos| / pdf through the BSDF's non-delta lobes, with
// a shadow ray. With `mis`, weighted by the power heuristic against BSDF sampling of the
// same direction (delta lights always get weight 1). The light is chosen by
// Scene::SampleLight at (hit.p, hit.ns): a caller weighing BSDF-sampled emitter hits asks
// Scene::LightPmf at the same point and normal. Inline, as it could be when it shared
// the path tracer's file: it runs at every vertex of the hot loops.
// `Shading` is BSDF, or one of its kinds when the caller knows which (PathIntegrator).
template <typename Shading, bool kLinks = true>
inline Color SampleDirectLight(const Scene& scene, const SurfaceHit& hit, const Shading& bsdf, const Frame& frame,
                               Vec3 wo, PixelSampler& sampler, bool mis) {
    const UnshadowedLightSample s = SampleDirectLightUnshadowed<Shading, kLinks>(scene, hit, bsdf, frame, wo, sampler, mis);
    if (!s.needs_shadow_ray) return Color(0.f);
    if (!(kLinks ? scene.UnoccludedToLight(s.light, hit.p, hit.p_error, hit.ng, s.ls)
                 : scene.Unoccluded(hit.p, hit.p_error, hit.ng, s.ls)))
        return Color(0.f);
    return s.contribution;
}

}  // namespace tessera
