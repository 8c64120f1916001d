// Unidirectional path tracing with next event estimation, multiple importance sampling
// (power heuristic over light sampling and BSDF sampling) and Russian roulette.
// Estimates L(D)*E paths of the lecture's full solution for Lambertian surfaces.
#pragma once

#include <limits>

#include "integrator.h"

namespace tessera {

class PathIntegrator final : public Integrator {
public:
    explicit PathIntegrator(int max_depth) : max_depth_(max_depth) {}
    static const IntegratorInfo& Info();
    const IntegratorInfo& info() const override { return Info(); }
    PathSample Sample(const Scene& scene, const Camera&, const CameraSample& cs, PixelSampler& sampler, SplatFilm&,
                      IntegratorCounters*) const override {
        return Li(scene, cs.ray, sampler, cs.t_min, cs.t_max);
    }
    // Radiance arriving along `ray`; max_depth bounds the number of scattering events.
    // [t_min, t_max] limits the first segment (the camera's clipping range).
    PathSample Li(const Scene& scene, Ray ray, PixelSampler& sampler, float t_min = 0.f,
                  float t_max = std::numeric_limits<float>::infinity()) const;

private:
    // The kernel, for shading through BSDF (any scene) or directly with DiffuseBSDF (a
    // scene whose materials are all Lambertian: no variant dispatch per BSDF call). Both
    // compute the same image to the bit on such a scene.
    template <typename Shading>
    PathSample Trace(const Scene& scene, Ray ray, PixelSampler& sampler, float t_min, float t_max) const;
    int max_depth_;
};

}  // namespace tessera
