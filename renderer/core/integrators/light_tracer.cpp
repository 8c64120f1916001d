#include "light_tracer.h"

#include "bsdf.h"
#include "bsdf_step.h"
#include "sampling.h"

namespace tessera {

const IntegratorInfo& LightTracer::Info() {
    static const IntegratorInfo info{
        .name = "light",
        .description = "light tracing: paths start on lights and splat onto the whole frame through the camera",
        .splats = true,
        .stop_per_tile = false,
        .delta_caustics = true,
        .handles_media = true,
        .traces_light_paths = true,
        .blind_to = {{"L S+ E", "a light path reaches the pinhole camera only by a connection from its last "
                                "vertex, and a smooth mirror or glass (a delta lobe) never connects"}},
    };
    return info;
}

IntegratorEntry LightTracerEntry() {
    return {LightTracer::Info, [](const IntegratorSettings& s, const Scene&) -> std::unique_ptr<Integrator> {
                return std::make_unique<LightTracer>(s.max_depth);
            }};
}

PathSample DirectlyVisibleLight(const Scene& scene, const Ray& ray, float t_min, float t_max) {
    PathSample result;
    SurfaceHit hit;
    if (scene.Intersect(ray, &hit, t_min, t_max)) {
        result.alpha = 1.f;
        if (int32_t e = scene.EmitterAt(hit); e != Scene::kNoEmitter) result.radiance = scene.Emitted(e, hit, -ray.d);
    } else {
        scene.ForEachEnvironmentLight(ray.o, ray.d, [&](uint32_t, Color Le, float) { result.radiance += Le; });
    }
    return result;
}

PathSample LightTracer::Sample(const Scene& scene, const Camera& camera, const CameraSample& cs, PixelSampler&,
                               SplatFilm& film, IntegratorCounters* counters) const {
    PathSample ps = scene.has_media() ? DirectlyVisibleLightThroughMedia(scene, cs.ray, cs.t_min, cs.t_max)
                                      : DirectlyVisibleLight(scene, cs.ray, cs.t_min, cs.t_max);
    PixelSampler light_sampler = cs.Stream(1);
    Trace(scene, camera, light_sampler, film, counters);
    return ps;
}

namespace {

// The geometry of a camera connection, with `visible(target)` the transmittance from p to
// the camera point `target` (0 or 1 without media).
template <typename Visible>
bool ConnectGeometry(const Camera& camera, Vec3 p, Vec2 u_lens, float* px, float* py, Vec3* wc,
                     float* importance_over_d2, Vec3* lens_point, Visible&& visible) {
    if (camera.IsOrthographic()) {
        // The one film point that sees p: its projection onto the film plane.
        const Vec3 v = p - camera.origin;
        const float depth = Dot(v, camera.forward);
        if (!(depth > 0.f) || depth < camera.near || depth > camera.far) return false;
        const Vec3 film = p - camera.forward * depth;
        float cos_camera;
        if (!camera.Project(film, camera.forward, px, py, &cos_camera)) return false;
        if (!visible(film, -camera.forward, depth)) return false;
        *wc = -camera.forward;
        *importance_over_d2 = 1.f / camera.ImagePlaneArea();  // parallel rays: no 1/d^2
        if (lens_point) *lens_point = film;
        return true;
    }
    const Vec3 lens = camera.LensPoint(u_lens);
    Vec3 to_camera = lens - p;
    float d2 = LengthSquared(to_camera);
    if (!(d2 > 0.f)) return false;
    float d = std::sqrt(d2), cos_camera;
    *wc = to_camera / d;
    if (!camera.Project(lens, -*wc, px, py, &cos_camera)) return false;
    const float depth = d * cos_camera;
    if (depth < camera.near || depth > camera.far) return false;
    if (!visible(lens, *wc, d)) return false;
    *importance_over_d2 = 1.f / (camera.ImagePlaneArea() * cos_camera * cos_camera * cos_camera * d2);
    if (lens_point) *lens_point = lens;
    return true;
}

}  // namespace

bool ConnectToCamera(const Scene& scene, const Camera& camera, Vec3 p, float p_error, Vec3 ng, Vec2 u_lens, float* px, float* py,
                     Vec3* wc, float* importance_over_d2, Vec3* lens_point) {
    return ConnectGeometry(camera, p, u_lens, px, py, wc, importance_over_d2, lens_point,
                           [&](Vec3 target, Vec3, float) { return scene.Unoccluded(p, p_error, ng, target, 0.f, Vec3(0.f)); });
}

bool ConnectToCameraThroughMedia(const Scene& scene, const Camera& camera, Vec3 p, float p_error, Vec3 ng,
                                 const MediumInterface& boundary, int32_t medium, Vec2 u_lens, float* px, float* py,
                                 Vec3* wc, float* importance_over_d2, Color* tr) {
    return ConnectGeometry(camera, p, u_lens, px, py, wc, importance_over_d2, nullptr,
                           [&](Vec3 target, Vec3 dir, float distance) {
                               LightSample to;  // the camera point as a point "light": no surface
                               to.wi = dir;
                               to.distance = distance;
                               to.p = target;
                               *tr = scene.Transmittance(p, p_error, ng, boundary.After(ng, dir, medium), to);
                               return !IsBlack(*tr);
                           });
}

bool LightTracer::StartLightPath(const Scene& scene, PixelSampler& sampler, LightPathStart* start) {
    const LightSampler& lights = scene.light_sampler();
    if (lights.empty()) return false;
    float pmf = 0.f;
    const uint32_t light = lights.Sample(sampler.Get1D(), &pmf);
    const Vec2 u_pos = sampler.Get2D(), u_dir = sampler.Get2D();
    const float u_side = sampler.Get1D();
    EmissionSample& es = start->es;
    if (!scene.SampleEmission(light, u_pos, u_dir, u_side, &es) || !(pmf > 0.f)) return false;
    start->beta = es.beta / pmf;
    start->ray = Ray{es.on_surface ? OffsetRayOrigin(es.p, es.p_error, es.n, es.wo) : es.p, es.wo};
    return true;
}

void LightTracer::Trace(const Scene& scene, const Camera& camera, PixelSampler& sampler, SplatFilm& film,
                        IntegratorCounters* counters) const {
    if (scene.has_media()) return TraceMedia(scene, camera, sampler, film, counters);
    LightPathStart start;
    if (!StartLightPath(scene, sampler, &start)) return;
    Color beta = start.beta;
    Ray ray = start.ray;
    float eta_scale = 1.f;
    const float roulette_scale = RouletteScale(beta);

    for (int depth = 1; depth <= max_depth_; ++depth) {
        SurfaceHit hit;
        if (!scene.Intersect(ray, &hit)) break;
        // Light paths carry importance's adjoint: BSDFs in Importance mode, with wo
        // pointing back toward the light.
        const BSDF bsdf = scene.BSDFAt(hit, TransportMode::Importance);
        if (bsdf.Flags() == kBSDFUnset) break;
        const Frame frame = Frame::FromZ(hit.ns);
        const Vec3 wo = -ray.d;
        const Vec3 wo_local = frame.ToLocal(wo);

        float px, py, importance;
        Vec3 wc;
        const Vec2 u_lens = sampler.Get2D();
        if (bsdf.IsNonSpecular() &&
            ConnectToCamera(scene, camera, hit.p, hit.p_error, hit.ng, u_lens, &px, &py, &wc, &importance)) {
            const Vec3 wc_local = frame.ToLocal(wc);
            Color contribution(0.f);
            if (SidesAgree(wo, wc, hit.ng, wo_local, wc_local))
                contribution = beta * bsdf.f(wo_local, wc_local) *
                               (std::abs(wc_local.z) * importance * ImportanceShadingCorrection(wo, wc, hit.ns, hit.ng));
            if (!IsBlack(contribution) && !film.Add(px, py, contribution) && counters) ++counters->rejected_splats;
        }
        if (depth == max_depth_) break;

        const std::optional<BSDFStep> step =
            SampleBSDFStep(bsdf, frame, wo, wo_local, hit.ng, sampler, beta,
                           [&](Vec3 w) { return ImportanceShadingCorrection(wo, w, hit.ns, hit.ng); });
        if (!step) break;
        const Vec3 wi = step->wi;
        if (step->sample.is_transmission) eta_scale *= step->sample.eta * step->sample.eta;
        ray = {OffsetRayOrigin(hit.p, hit.p_error, hit.ng, wi), wi};
        if (depth >= 3) {
            float q = std::min(1.f, MaxComponent(beta) * eta_scale * roulette_scale);
            if (sampler.Get1D() >= q) break;
            beta = beta / q;
        }
    }
}

}  // namespace tessera
