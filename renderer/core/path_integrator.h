// Unidirectional path tracing with next event estimation, multiple importance sampling
// (power heuristic over light sampling and BSDF sampling) and Russian roulette.
// Estimates L(D)*E paths of the lecture's full solution for Lambertian surfaces.
#pragma once

#include <limits>

#include "camera.h"
#include "sampler.h"
#include "scene.h"

namespace tessera {

struct PathSample {
    Color radiance;
    float alpha = 0.f;  // 1 where the camera ray hit geometry
};

// One light sample at a surface: Le f |cos| / pdf through the BSDF's non-delta lobes, with
// a shadow ray. With `mis`, weighted by the power heuristic against BSDF sampling of the
// same direction (delta lights always get weight 1).
Color SampleDirectLight(const Scene& scene, const SurfaceHit& hit, const BSDF& bsdf, const Frame& frame, Vec3 wo,
                        PixelSampler& sampler, bool mis);

class PathIntegrator {
public:
    explicit PathIntegrator(int max_depth) : max_depth_(max_depth) {}
    // Radiance arriving along `ray`; max_depth bounds the number of scattering events.
    // [t_min, t_max] limits the first segment (the camera's clipping range).
    PathSample Li(const Scene& scene, Ray ray, PixelSampler& sampler, float t_min = 0.f,
                  float t_max = std::numeric_limits<float>::infinity()) const;

private:
    int max_depth_;
};

}  // namespace tessera
