// Whitted ray tracing (1980; the lecture's method 2), L [D|S] S_M* E: direct light at
// every surface (next event estimation, shadow rays), and recursion only along ideal
// mirror reflection and refraction (the BSDF's delta lobes). Glossy and diffuse
// interreflection and caustics (L S D) are not part of the method and stay dark.
#pragma once

#include <limits>

#include "integrator.h"

namespace tessera {

class WhittedIntegrator final : public Integrator {
public:
    explicit WhittedIntegrator(int max_depth) : max_depth_(max_depth) {}
    static const IntegratorInfo& Info();
    const IntegratorInfo& info() const override { return Info(); }
    PathSample Sample(const Scene& scene, const Camera&, const CameraSample& cs, PixelSampler& sampler, SplatFilm&,
                      IntegratorCounters*) const override {
        return Li(scene, cs.ray, sampler, cs.t_min, cs.t_max);
    }
    // [t_min, t_max] limits the first segment (the camera's clipping range).
    PathSample Li(const Scene& scene, Ray ray, PixelSampler& sampler, float t_min = 0.f,
                  float t_max = std::numeric_limits<float>::infinity()) const;

private:
    int max_depth_;
};

}  // namespace tessera
