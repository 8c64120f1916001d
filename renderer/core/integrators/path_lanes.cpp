#include "path_lanes.h"

#include <algorithm>
#include <stdexcept>

#include "bsdf.h"
#include "bsdf_step.h"
#include "direct_light.h"
#include "sampling.h"

namespace tessera {

int DefaultLaneWidth() {
    static const int width = __builtin_cpu_supports("avx2") ? 8 : 4;
    return width;
}

bool LaneKernelApplies(const Scene& scene) {
    // Media need the media kernel's free flights (path_media.cpp), whatever the surfaces are.
    // Light links need the scalar kernel's per-vertex link groups.
    return scene.all_lambertian() && scene.packets_apply() && !scene.has_motion() && !scene.has_media() &&
           !scene.has_light_links();
}

namespace {

constexpr int kLanes = Scene::kMaxPacket;

// The group's paths, one array element per lane.
struct LaneGroup {
    bool active[kLanes] = {};
    size_t sample[kLanes] = {};  // the pixel sample the lane traces
    int depth[kLanes] = {};
    Ray ray[kLanes];
    float t_min[kLanes] = {}, t_max[kLanes] = {};
    Color L[kLanes], beta[kLanes];
    float bsdf_pdf[kLanes] = {};
    bool specular_bounce[kLanes] = {};
    Vec3 prev_p[kLanes], prev_n[kLanes];
    float alpha[kLanes] = {};
    SurfaceHit hit[kLanes];
    bool found[kLanes] = {};
    // This vertex's light sample, waiting for the group's shadow rays.
    bool nee[kLanes] = {};
    Color nee_beta[kLanes];
    UnshadowedLightSample light[kLanes];
    bool ends[kLanes] = {};  // the path ends after this vertex's light sample
};

// One vertex of lane i, Trace<DiffuseBSDF>'s loop body up to the shadow ray of its light
// sample (whose outcome nothing after it reads).
void ShadeVertex(const Scene& scene, int max_depth, int roulette_depth, LaneGroup& g, int i, PixelSampler& sampler) {
    const int depth = g.depth[i];
    Color& L = g.L[i];
    Color& beta = g.beta[i];
    g.nee[i] = false;
    g.ends[i] = true;
    const Ray& ray = g.ray[i];
    if (!g.found[i]) {
        scene.ForEachEnvironmentLight(ray.o, ray.d, [&](uint32_t light, Color Le, float pdf) {
            float w = (depth == 0 || g.specular_bounce[i])
                          ? 1.f
                          : PowerHeuristic(g.bsdf_pdf[i], scene.LightPmf(g.prev_p[i], g.prev_n[i], light) * pdf);
            L += beta * Le * w;
        });
        return;
    }
    const SurfaceHit& hit = g.hit[i];
    if (depth == 0) g.alpha[i] = 1.f;
    const Vec3 wo = -ray.d;
    if (int32_t e = scene.EmitterAt(hit); e != Scene::kNoEmitter) {
        Color Le = scene.Emitted(e, hit, wo);
        if (!IsBlack(Le)) {
            float w = 1.f;
            if (depth > 0 && !g.specular_bounce[i])
                w = PowerHeuristic(g.bsdf_pdf[i], scene.LightPmf(g.prev_p[i], g.prev_n[i], uint32_t(e)) *
                                                      scene.EmitterPdf(e, g.prev_p[i], hit));
            L += beta * Le * w;
        }
    }
    if (depth >= max_depth) return;
    const DiffuseBSDF bsdf(scene.LambertianAlbedoAt(hit));
    if (bsdf.Flags() == kBSDFUnset) return;
    const Frame frame = Frame::FromZ(hit.ns);
    const Vec3 wo_local = frame.ToLocal(wo);
    if (!scene.light_sampler().empty() && bsdf.IsNonSpecular()) {
        g.nee[i] = true;
        g.nee_beta[i] = beta;
        // Never a scene with light links (LaneKernelApplies): their checks compiled out.
        g.light[i] = SampleDirectLightUnshadowed<DiffuseBSDF, false>(scene, hit, bsdf, frame, wo, sampler, /*mis=*/true);
    }
    const std::optional<BSDFStep> step = SampleBSDFStep(bsdf, frame, wo, wo_local, hit.ng, sampler, beta);
    if (!step) return;
    const BSDFSample* bs = &step->sample;
    const Vec3 wi = step->wi;
    g.bsdf_pdf[i] = bs->pdf;
    g.specular_bounce[i] = bs->is_specular;
    // Lambertian reflection never refracts: the scalar kernel's eta scale stays 1.
    g.prev_p[i] = hit.p;
    g.prev_n[i] = hit.ns;
    g.ray[i] = {OffsetRayOrigin(hit.p, hit.p_error, hit.ng, wi), wi};
    g.t_min[i] = 0.f;
    g.t_max[i] = std::numeric_limits<float>::infinity();
    if (depth >= roulette_depth) {
        float q = std::min(1.f, MaxComponent(beta));
        if (sampler.Get1D() >= q) return;
        beta = beta / q;
    }
    g.depth[i] = depth + 1;
    g.ends[i] = false;
}

}  // namespace

void TraceLanes(const Scene& scene, int width, int max_depth, int roulette_depth, BatchSample* samples,
                PathSample* out, size_t n) {
    if (width != 1 && width != 4 && width != 8) throw std::invalid_argument("lane width must be 1, 4 or 8");
    LaneGroup g;
    size_t next = 0;
    for (;;) {
        // Regenerate: every idle lane takes the next pixel sample.
        bool any = false;
        for (int i = 0; i < width; ++i) {
            if (!g.active[i] && next < n) {
                const BatchSample& s = samples[next];
                g.active[i] = true;
                g.sample[i] = next++;
                g.depth[i] = 0;
                g.ray[i] = s.ray;
                g.t_min[i] = s.t_min;
                g.t_max[i] = s.t_max;
                g.L[i] = Color(0.f);
                g.beta[i] = Color(1.f);
                g.bsdf_pdf[i] = 0.f;
                g.specular_bounce[i] = false;
                g.alpha[i] = 0.f;
            }
            any |= g.active[i];
        }
        if (!any) return;
        scene.IntersectPacket(width, g.active, g.ray, g.t_min, g.t_max, g.hit, g.found);
        for (int i = 0; i < width; ++i)
            if (g.active[i]) ShadeVertex(scene, max_depth, roulette_depth, g, i, samples[g.sample[i]].sampler);
        // Shadow rays one at a time: Embree's packets did not pay for them (rays.md).
        for (int i = 0; i < width; ++i) {
            if (!g.active[i]) continue;
            if (g.nee[i]) {
                const UnshadowedLightSample& s = g.light[i];
                const bool lit = s.needs_shadow_ray && scene.Unoccluded(g.hit[i].p, g.hit[i].p_error, g.hit[i].ng, s.ls);
                g.L[i] += g.nee_beta[i] * (lit ? s.contribution : Color(0.f));
            }
            if (g.ends[i]) {
                out[g.sample[i]] = {g.L[i], g.alpha[i]};
                g.active[i] = false;
            }
        }
    }
}

}  // namespace tessera
