// PathIntegrator's kernel for scenes with participating media (media/medium.h): the
// surface kernel of path.cpp plus free-flight sampling in the medium a segment runs
// through, scattering by the Henyey-Greenstein phase function, next event estimation at
// medium vertices and Beer-Lambert transmittance on every shadow ray through the
// boundaries between. Scenes without media never enter it (PathIntegrator::Li), so their
// images and speed are those of the surface kernel. A grid medium (media/grid_medium.h)
// samples its free flights by delta tracking and its transmittance by ratio tracking; its
// sample has the homogeneous one's meaning, so the kernel treats both alike.
//
// Boundaries follow pbrt-v4: a surface whose material is a pure interface
// (Material::interface_only) has no BSDF; a ray passes it unchanged, entering the medium
// on the far side, and it is no vertex of the path (depth, MIS and roulette ignore it). A
// scattering surface with a medium interface (e.g. glass around a medium) hands the path
// to the medium on the side it leaves toward.
#include <cmath>
#include <limits>

#include "bsdf.h"
#include "bsdf_step.h"
#include "path.h"
#include "phase.h"
#include "sampling.h"

namespace tessera {

namespace {

constexpr int kMaxBoundaryCrossings = 256;  // per segment, as Scene::Transmittance

// One light sample for a vertex at p (a surface point with geometric normal ng and error
// bound, or a medium point: ng = 0, error 0), weighted by the power heuristic against the
// vertex's own sampling: Le T f / pdf. `eval(wi, &pdf)` returns the scattering function
// times the cosine (a surface) or the phase function (a medium) and its sampling density.
// `medium_toward(wi)` is the medium the shadow ray starts in.
template <typename Eval, typename MediumToward>
Color DirectLightThroughMedia(const Scene& scene, Vec3 p, float p_error, Vec3 ng, Vec3 pmf_normal,
                              PixelSampler& sampler, Eval&& eval, MediumToward&& medium_toward) {
    float pmf = 0.f;
    uint32_t light = 0;
    const bool chosen = scene.SampleLight(sampler.Get1D(), p, pmf_normal, &light, &pmf);
    const Vec2 u = sampler.Get2D();  // drawn either way: the dimensions after it stay put
    if (!chosen) return Color(0.f);
    LightSample ls;
    if (!scene.SampleEmitter(light, p, u, &ls)) return Color(0.f);
    const float light_pdf = pmf * ls.pdf;
    if (!(light_pdf > 0.f)) return Color(0.f);
    float scatter_pdf = 0.f;
    const Color f = eval(ls.wi, &scatter_pdf);
    if (IsBlack(f)) return Color(0.f);
    const Color tr = scene.Transmittance(p, p_error, ng, medium_toward(ls.wi), ls);
    if (IsBlack(tr)) return Color(0.f);
    const float w = ls.is_delta ? 1.f : PowerHeuristic(light_pdf, scatter_pdf);
    return f * tr * ls.radiance * (w / light_pdf);
}

}  // namespace

PathSample PathIntegrator::TraceMedia(const Scene& scene, Ray ray, PixelSampler& sampler, float t_min,
                                      float t_max) const {
    PathSample result;
    Color L(0.f), beta(1.f);
    float scatter_pdf = 0.f;       // solid-angle pdf of the direction that produced `ray`
    bool specular_bounce = false;  // ...and whether it came from a delta lobe (no MIS then)
    float eta_scale = 1.f;
    Vec3 prev_p, prev_n;  // the last vertex and its normal (zero at a medium vertex)
    int32_t medium = scene.MediumAt(ray.o);
    // Free flights use the hero channel's coefficients; r holds each channel's path density
    // over the hero's, and a contribution is divided by their mean: the balance heuristic
    // over channels on the whole path (media/medium.h). The hero's own entry stays 1.
    const int hero = HeroChannel(sampler.Get1D());
    Color r(1.f);
    auto over_r = [&r] { return 3.f / (r.x + r.y + r.z); };
    bool camera_segment = true;  // t_min / t_max clip the camera ray's segments only
    int crossings = 0;

    for (int depth = 0;;) {
        SurfaceHit hit;
        const bool found = camera_segment ? scene.Intersect(ray, &hit, t_min, t_max) : scene.Intersect(ray, &hit);
        if (found && camera_segment) result.alpha = 1.f;

        if (medium >= 0) {
            const GridMedium* grid = scene.grid_medium(medium);
            // The segment ends at the hit, or at the camera's far clip, or never.
            const float end = found ? hit.t : camera_segment ? t_max : std::numeric_limits<float>::infinity();
            const MediumSample ms = grid ? SampleFreeFlight(*grid, ray.o, ray.d, end, hero, sampler.Get1D())
                                         : SampleFreeFlight(scene.medium(medium), end, hero, sampler.Get1D());
            const float hero_pdf = ms.HeroPdf(hero);
            if (!(hero_pdf > 0.f)) break;
            beta *= ms.f * (1.f / hero_pdf);
            r *= ms.pdf * (1.f / hero_pdf);
            if (IsBlack(beta)) break;
            if (ms.scattered) {
                if (depth >= max_depth_) break;
                const Vec3 p = ray.o + ray.d * ms.t;
                const HGPhase phase{grid ? grid->g : scene.medium(medium).g};
                if (!scene.light_sampler().empty())
                    L += beta * over_r() * DirectLightThroughMedia(
                                    scene, p, 0.f, Vec3(0.f), Vec3(0.f), sampler,
                                    [&](Vec3 wi, float* pdf) {
                                        *pdf = phase.p(ray.d, wi);
                                        return Color(*pdf);
                                    },
                                    [&](Vec3) { return medium; });
                const PhaseSample ps = phase.Sample(ray.d, sampler.Get2D());
                if (!(ps.pdf > 0.f)) break;
                // The phase function is sampled exactly: its value over its pdf is 1.
                scatter_pdf = ps.pdf;
                specular_bounce = false;
                prev_p = p;
                prev_n = Vec3(0.f);
                ray = {p, ps.wi};
                camera_segment = false;
                crossings = 0;
                if (depth++ >= roulette_depth_) {
                    const float q = std::min(1.f, MaxComponent(beta) * eta_scale * over_r());
                    if (sampler.Get1D() >= q) break;
                    beta = beta / q;
                }
                continue;
            }
        }

        if (!found) {
            scene.ForEachEnvironmentLight(ray.o, ray.d, [&](uint32_t light, Color Le, float pdf) {
                const float w = (depth == 0 || specular_bounce)
                                    ? 1.f
                                    : PowerHeuristic(scatter_pdf, scene.LightPmf(prev_p, prev_n, light) * pdf);
                L += beta * Le * (w * over_r());
            });
            break;
        }

        if (scene.IsInterfaceOnly(hit)) {
            // Not a vertex: the ray goes on into the medium beyond, clipped as before.
            if (++crossings > kMaxBoundaryCrossings) break;
            medium = scene.MediumInterfaceAt(hit).After(hit.ng, ray.d, medium);
            ray.o = OffsetRayOrigin(hit.p, hit.p_error, hit.ng, ray.d);
            if (camera_segment) {
                t_min = std::max(0.f, t_min - hit.t);
                t_max -= hit.t;
            }
            continue;
        }
        crossings = 0;
        const Vec3 wo = -ray.d;

        if (int32_t e = scene.EmitterAt(hit); e != Scene::kNoEmitter) {
            const Color Le = scene.Emitted(e, hit, wo);
            if (!IsBlack(Le)) {
                float w = 1.f;
                if (depth > 0 && !specular_bounce)
                    w = PowerHeuristic(scatter_pdf, scene.LightPmf(prev_p, prev_n, uint32_t(e)) *
                                                        scene.EmitterPdf(e, prev_p, hit));
                L += beta * Le * (w * over_r());
            }
        }
        if (depth >= max_depth_) break;

        const BSDF bsdf = scene.BSDFAt(hit, TransportMode::Radiance);
        if (bsdf.Flags() == kBSDFUnset) break;
        const Frame frame = Frame::FromZ(hit.ns);
        const Vec3 wo_local = frame.ToLocal(wo);
        const MediumInterface& boundary = scene.MediumInterfaceAt(hit);

        if (!scene.light_sampler().empty() && bsdf.IsNonSpecular())
            L += beta * over_r() * DirectLightThroughMedia(
                            scene, hit.p, hit.p_error, hit.ng, hit.ns, sampler,
                            [&](Vec3 wi, float* pdf) {
                                const Vec3 wi_local = frame.ToLocal(wi);
                                if (!SidesAgree(wo, wi, hit.ng, wo_local, wi_local)) return Color(0.f);
                                *pdf = bsdf.PDF(wo_local, wi_local);
                                return bsdf.f(wo_local, wi_local) * std::abs(wi_local.z);
                            },
                            [&](Vec3 wi) { return boundary.After(hit.ng, wi, medium); });

        const std::optional<BSDFStep> step = SampleBSDFStep(bsdf, frame, wo, wo_local, hit.ng, sampler, beta);
        if (!step) break;
        const BSDFSample* bs = &step->sample;
        const Vec3 wi = step->wi;
        scatter_pdf = bs->pdf;
        specular_bounce = bs->is_specular;
        if (bs->is_transmission) eta_scale *= bs->eta * bs->eta;
        prev_p = hit.p;
        prev_n = hit.ns;
        medium = boundary.After(hit.ng, wi, medium);
        ray = {OffsetRayOrigin(hit.p, hit.p_error, hit.ng, wi), wi};
        camera_segment = false;

        if (depth++ >= roulette_depth_) {
            const float q = std::min(1.f, MaxComponent(beta) * eta_scale * over_r());
            if (sampler.Get1D() >= q) break;
            beta = beta / q;
        }
    }
    result.radiance = L;
    return result;
}

}  // namespace tessera
