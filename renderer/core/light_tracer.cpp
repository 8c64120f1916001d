#include "light_tracer.h"

#include "sampling.h"

namespace tessera {

namespace {

// Connects surface point p (normal n facing the side the light came from) to the pinhole.
// Returns false if the camera cannot see p. Writes the raster position and the importance
// factor We cos_camera / d^2 = 1 / (A cos^3 theta_camera d^2).
bool ConnectToCamera(const Scene& scene, const Camera& camera, Vec3 p, Vec3 n, float* px, float* py, Vec3* wc,
                     float* importance_over_d2) {
    Vec3 to_camera = camera.origin - p;
    float d2 = LengthSquared(to_camera);
    if (!(d2 > 0.f)) return false;
    float d = std::sqrt(d2);
    *wc = to_camera / d;
    if (Dot(*wc, n) <= 0.f) return false;  // the camera is behind the surface
    Vec3 dir = -*wc;                       // camera ray direction toward p
    float cos_camera = Dot(dir, camera.forward);
    if (cos_camera <= 0.f) return false;
    float sx = Dot(dir, camera.right) / cos_camera / camera.tan_half_width;
    float sy = Dot(dir, camera.up) / cos_camera / camera.tan_half_height;
    *px = (sx + 1.f) * 0.5f * float(camera.width);
    *py = (1.f - sy) * 0.5f * float(camera.height);
    if (!(*px >= 0.f && *px < float(camera.width) && *py >= 0.f && *py < float(camera.height))) return false;
    if (scene.Occluded(OffsetRayOrigin(p, n, *wc), *wc, d * (1.f - 1e-4f))) return false;
    const float area = 4.f * camera.tan_half_width * camera.tan_half_height;
    *importance_over_d2 = 1.f / (area * cos_camera * cos_camera * cos_camera * d2);
    return true;
}

}  // namespace

void LightTracer::Trace(const Scene& scene, const Camera& camera, PixelSampler& sampler, SplatFilm& film,
                        LightTraceStats* stats) const {
    const LightSampler& lights = scene.light_sampler();
    if (lights.empty()) return;
    float pmf = 0.f;
    uint32_t light = lights.Sample(sampler.Get1D(), &pmf);
    Vec2 u_pos = sampler.Get2D(), u_dir = sampler.Get2D();
    float u_side = sampler.Get1D();
    EmissionSample es;
    if (!scene.SampleEmission(light, u_pos, u_dir, u_side, &es) || !(pmf > 0.f)) return;
    Color beta = es.beta / pmf;
    Ray ray{es.on_surface ? OffsetRayOrigin(es.p, es.n, es.wo) : es.p, es.wo};

    for (int depth = 1; depth <= max_depth_; ++depth) {
        SurfaceHit hit;
        if (!scene.Intersect(ray, &hit)) break;
        const Material& m = scene.MaterialAt(hit);
        if (IsBlack(m.albedo)) break;
        const Vec3 wo = -ray.d;
        // Lambertian reflection only: the camera must be on the side the light came from.
        const Vec3 n = Dot(hit.ng, wo) >= 0.f ? hit.ng : -hit.ng;
        const Color f = m.albedo * kInvPi;

        float px, py, importance;
        Vec3 wc;
        if (ConnectToCamera(scene, camera, hit.p, n, &px, &py, &wc, &importance)) {
            Color contribution = beta * f * (Dot(n, wc) * importance);
            if (!film.Add(px, py, contribution) && stats) ++stats->rejected_splats;
        }
        if (depth == max_depth_) break;

        // Continue by cosine-weighted sampling: f cos / pdf = albedo (Lambertian is
        // symmetric, so importance transport needs no correction here).
        Vec3 local = SampleCosineHemisphere(sampler.Get2D());
        if (!(local.z > 0.f)) break;
        Vec3 wi = Normalize(Frame::FromZ(n).FromLocal(local));
        beta *= m.albedo;
        ray = {OffsetRayOrigin(hit.p, n, wi), wi};
        if (depth >= 3) {
            float q = std::min(1.f, MaxComponent(beta));
            if (sampler.Get1D() >= q) break;
            beta = beta / q;
        }
    }
}

}  // namespace tessera
