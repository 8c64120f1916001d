// Light tracing (Arvo 1986; the lecture's method 9): paths start on lights, and every
// scattering vertex is connected to the pinhole camera through its importance function,
// splatting onto the full frame. Estimates the L(D)+E paths; light reaching the camera
// without scattering (emitters and the sky seen directly) comes from the camera rays of
// the tile's own pixels instead, as a pinhole can never be hit by a light path.
//
// Normalisation (the one formula is in render.h and tessera_renderer/film.py): with
// We = 1 / (A cos^4 theta) over the image plane at distance 1 of area A, a pixel's value
// is sum(splats) * pixel_count / light_paths.
#pragma once

#include "integrator.h"

namespace tessera {

// Connects point p (within p_error of its surface, geometric normal ng: for the ray
// offset) to the camera: false if the
// camera cannot see p (outside the image, beyond the clipping range, occluded). Writes the
// raster position, the unit direction to the camera and the importance estimate
// We cos_camera / (d^2 pdf_lens) = 1 / (A cos^3 theta_camera d^2) (the lens area cancels).
// With a thin lens, u_lens picks the lens point the connection goes to; *lens_point gets it.
// Orthographic: the connection goes to p's projection on the film along -forward, and the
// estimate is 1 / A (parallel rays; camera.h).
bool ConnectToCamera(const Scene& scene, const Camera& camera, Vec3 p, float p_error, Vec3 ng, Vec2 u_lens, float* px, float* py,
                     Vec3* wc, float* importance_over_d2, Vec3* lens_point = nullptr);

// As ConnectToCamera in a scene with media (docs/media.md): the connection leaves p into
// the medium `boundary` gives toward the camera, having been in `medium` (a medium vertex
// passes no boundary: ng 0), passes pure medium interfaces, and *tr gets the transmittance
// along it (Scene::Transmittance); false where that is black. Importance as
// ConnectToCamera's.
bool ConnectToCameraThroughMedia(const Scene& scene, const Camera& camera, Vec3 p, float p_error, Vec3 ng,
                                 const MediumInterface& boundary, int32_t medium, Vec2 u_lens, float* px, float* py,
                                 Vec3* wc, float* importance_over_d2, Color* tr);

// What a pinhole sees without scattering: emitters and lights at infinity along the ray.
PathSample DirectlyVisibleLight(const Scene& scene, const Ray& ray, float t_min, float t_max);
// The same through media: pure interfaces passed, attenuated by Beer-Lambert along the ray.
PathSample DirectlyVisibleLightThroughMedia(const Scene& scene, const Ray& ray, float t_min, float t_max);

class LightTracer final : public Integrator {
public:
    explicit LightTracer(int max_depth) : max_depth_(max_depth) {}
    static const IntegratorInfo& Info();
    const IntegratorInfo& info() const override { return Info(); }
    // The camera ray gives the light seen unscattered; one light path (stream 1 of the
    // sample) is traced and splatted.
    PathSample Sample(const Scene& scene, const Camera& camera, const CameraSample& cs, PixelSampler& sampler,
                      SplatFilm& film, IntegratorCounters* counters) const override;
    // Traces one light path with the given sampler and splats its camera connections.
    // Splats that are non-finite, negative or unrepresentable are counted (a bug if any).
    void Trace(const Scene& scene, const Camera& camera, PixelSampler& sampler, SplatFilm& film,
               IntegratorCounters* counters) const;

private:
    // A light path's first vertex: a light chosen by the scene's light sampler, then a point
    // and direction on it (the next five sampler dimensions), its throughput divided by
    // both densities, and the ray leaving it. False when nothing can be emitted.
    struct LightPathStart {
        EmissionSample es;
        Color beta;
        Ray ray;
    };
    static bool StartLightPath(const Scene& scene, PixelSampler& sampler, LightPathStart* start);
    // Trace's kernel for scenes with media (light_tracer_media.cpp).
    void TraceMedia(const Scene& scene, const Camera& camera, PixelSampler& sampler, SplatFilm& film,
                    IntegratorCounters* counters) const;
    int max_depth_;
};

}  // namespace tessera
