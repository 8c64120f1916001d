// LightTracer's kernel for scenes with participating media (media/medium.h; docs/media.md):
// light paths take free flights through the medium each segment runs in, scatter by the
// Henyey-Greenstein phase function, and every vertex -- in a medium or on a surface --
// connects to the camera with the Beer-Lambert transmittance of the connection through
// the pure interfaces between. The camera rays' directly visible light is attenuated the
// same way. Scenes without media never enter it (LightTracer::Trace), so their images are
// the surface kernel's.
//
// Free flights, the hero channel and its MIS over channels are the path tracer's
// (path_media.cpp): distances sampled against sigma_s of one channel chosen per light
// path, absorption carried as a weight, and each contribution divided by the mean of the
// channels' path densities over the hero's.
#include <cmath>
#include <limits>

#include "bsdf.h"
#include "bsdf_step.h"
#include "light_tracer.h"
#include "phase.h"
#include "sampling.h"

namespace tessera {

namespace {
constexpr int kMaxBoundaryCrossings = 256;  // per segment, as Scene::Transmittance
}  // namespace

PathSample DirectlyVisibleLightThroughMedia(const Scene& scene, const Ray& camera_ray, float t_min, float t_max) {
    PathSample result;
    Ray ray = camera_ray;
    int32_t medium = scene.MediumAt(ray.o);
    Color tr(1.f);
    for (int crossing = 0; crossing < kMaxBoundaryCrossings; ++crossing) {
        SurfaceHit hit;
        if (!scene.Intersect(ray, &hit, t_min, t_max)) {
            if (std::isinf(t_max)) {  // a medium's infinite segment lets nothing through
                if (medium >= 0) tr *= scene.medium(medium).Transmittance(t_max);
                if (!IsBlack(tr))
                    scene.ForEachEnvironmentLight(ray.o, ray.d, [&](uint32_t, Color Le, float) { result.radiance += Le * tr; });
            }
            return result;
        }
        result.alpha = 1.f;
        if (medium >= 0) tr *= scene.medium(medium).Transmittance(hit.t);
        if (!scene.IsInterfaceOnly(hit)) {
            if (int32_t e = scene.EmitterAt(hit); e != Scene::kNoEmitter)
                result.radiance = scene.Emitted(e, hit, -ray.d) * tr;
            return result;
        }
        medium = scene.MediumInterfaceAt(hit).After(hit.ng, ray.d, medium);
        ray.o = OffsetRayOrigin(hit.p, hit.p_error, hit.ng, ray.d);
        t_min = std::max(0.f, t_min - hit.t);
        t_max -= hit.t;
    }
    return result;
}

void LightTracer::TraceMedia(const Scene& scene, const Camera& camera, PixelSampler& sampler, SplatFilm& film,
                             IntegratorCounters* counters) const {
    if (max_depth_ < 1) return;
    LightPathStart start;
    if (!StartLightPath(scene, sampler, &start)) return;
    Color beta = start.beta;
    Ray ray = start.ray;
    float eta_scale = 1.f;
    const float roulette_scale = RouletteScale(beta);
    int32_t medium = scene.MediumAt(ray.o);
    const int hero = HeroChannel(sampler.Get1D());
    Color r(1.f);
    auto over_r = [&r] { return 3.f / (r.x + r.y + r.z); };
    auto splat = [&](float px, float py, Color contribution) {
        if (!IsBlack(contribution) && !film.Add(px, py, contribution) && counters) ++counters->rejected_splats;
    };
    // After vertex `depth` scattered into a new direction: Russian roulette as the surface
    // kernel plays it, on the MIS-weighted throughput.
    auto survives = [&](int depth) {
        if (depth < 3) return true;
        const float q = std::min(1.f, MaxComponent(beta) * eta_scale * roulette_scale * over_r());
        if (sampler.Get1D() >= q) return false;
        beta = beta / q;
        return true;
    };
    int crossings = 0;

    for (int depth = 1;;) {
        SurfaceHit hit;
        const bool found = scene.Intersect(ray, &hit);
        if (medium >= 0) {
            const HomogeneousMedium& m = scene.medium(medium);
            const float end = found ? hit.t : std::numeric_limits<float>::infinity();
            const MediumSample ms = SampleFreeFlight(m, end, hero, sampler.Get1D());
            const float hero_pdf = ms.HeroPdf(hero);
            if (!(hero_pdf > 0.f)) break;
            beta *= ms.f * (1.f / hero_pdf);
            r *= ms.pdf * (1.f / hero_pdf);
            if (IsBlack(beta)) break;
            if (ms.scattered) {
                const Vec3 p = ray.o + ray.d * ms.t;
                const HGPhase phase{m.g};
                float px, py, importance;
                Vec3 wc;
                Color tr;
                const Vec2 u_lens = sampler.Get2D();
                if (ConnectToCameraThroughMedia(scene, camera, p, 0.f, Vec3(0.f), MediumInterface{}, medium, u_lens,
                                                &px, &py, &wc, &importance, &tr))
                    splat(px, py, beta * tr * (phase.p(ray.d, wc) * importance * over_r()));
                if (depth == max_depth_) break;
                // The phase function is sampled exactly: its value over its pdf is 1.
                const PhaseSample ps = phase.Sample(ray.d, sampler.Get2D());
                if (!(ps.pdf > 0.f)) break;
                ray = {p, ps.wi};
                crossings = 0;
                if (!survives(depth++)) break;
                continue;
            }
        }
        if (!found) break;
        if (scene.IsInterfaceOnly(hit)) {
            // Not a vertex: the light goes on into the medium beyond.
            if (++crossings > kMaxBoundaryCrossings) break;
            medium = scene.MediumInterfaceAt(hit).After(hit.ng, ray.d, medium);
            ray.o = OffsetRayOrigin(hit.p, hit.p_error, hit.ng, ray.d);
            continue;
        }
        crossings = 0;
        // Light paths carry importance's adjoint: BSDFs in Importance mode, with wo
        // pointing back toward the light.
        const BSDF bsdf = scene.BSDFAt(hit, TransportMode::Importance);
        if (bsdf.Flags() == kBSDFUnset) break;
        const Frame frame = Frame::FromZ(hit.ns);
        const Vec3 wo = -ray.d;
        const Vec3 wo_local = frame.ToLocal(wo);
        const MediumInterface& boundary = scene.MediumInterfaceAt(hit);

        float px, py, importance;
        Vec3 wc;
        Color tr;
        const Vec2 u_lens = sampler.Get2D();
        if (bsdf.IsNonSpecular() && ConnectToCameraThroughMedia(scene, camera, hit.p, hit.p_error, hit.ng, boundary,
                                                                 medium, u_lens, &px, &py, &wc, &importance, &tr)) {
            const Vec3 wc_local = frame.ToLocal(wc);
            if (SidesAgree(wo, wc, hit.ng, wo_local, wc_local))
                splat(px, py,
                      beta * tr * bsdf.f(wo_local, wc_local) *
                          (std::abs(wc_local.z) * importance * ImportanceShadingCorrection(wo, wc, hit.ns, hit.ng) *
                           over_r()));
        }
        if (depth == max_depth_) break;

        const std::optional<BSDFStep> step =
            SampleBSDFStep(bsdf, frame, wo, wo_local, hit.ng, sampler, beta,
                           [&](Vec3 w) { return ImportanceShadingCorrection(wo, w, hit.ns, hit.ng); });
        if (!step) break;
        const Vec3 wi = step->wi;
        if (step->sample.is_transmission) eta_scale *= step->sample.eta * step->sample.eta;
        medium = boundary.After(hit.ng, wi, medium);
        ray = {OffsetRayOrigin(hit.p, hit.p_error, hit.ng, wi), wi};
        if (!survives(depth++)) break;
    }
}

}  // namespace tessera
