// Whitted ray tracing (1980; the lecture's method 2), L [D|S] S_M* E: direct light at
// every surface (next event estimation, shadow rays), and recursion only along ideal
// mirror reflection and refraction (the BSDF's delta lobes). Glossy and diffuse
// interreflection and caustics (L S D) are not part of the method and stay dark.
#pragma once

#include <limits>

#include "camera.h"
#include "path_integrator.h"
#include "sampler.h"
#include "scene.h"

namespace tessera {

class WhittedIntegrator {
public:
    explicit WhittedIntegrator(int max_depth) : max_depth_(max_depth) {}
    // [t_min, t_max] limits the first segment (the camera's clipping range).
    PathSample Li(const Scene& scene, Ray ray, PixelSampler& sampler, float t_min = 0.f,
                  float t_max = std::numeric_limits<float>::infinity()) const;

private:
    int max_depth_;
};

}  // namespace tessera
