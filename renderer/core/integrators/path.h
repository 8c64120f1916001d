// Unidirectional path tracing with next event estimation, multiple importance sampling
// (power heuristic over light sampling and BSDF sampling) and Russian roulette.
// Estimates L(D)*E paths of the lecture's full solution for Lambertian surfaces.
#pragma once

#include <limits>

#include "integrator.h"

namespace tessera {

class PathIntegrator final : public Integrator {
public:
    // Russian roulette may end a path from this vertex index on (0 = the first hit). Earlier
    // roulette shortens paths but its coin flips are noise the sampler's stratification
    // cannot remove: on the Lambertian Cornell boxes, starting at the sixth vertex (5)
    // instead of the third (2) costs 1.4x the time per sample for 1.5-1.6x less error,
    // 14-16 % less time to an error (docs/benchmarks/russian-roulette.md). The default stays
    // 2: on the Cornell box with a mirror and a glass sphere, 5 gave the ceiling (lit through
    // them) a heavy tail, one seed in six 6 % bright (tests/renderer/test_radiosity.py).
    static constexpr int kDefaultRouletteDepth = 2;
    // lanes: 0 for the scalar kernel, else the lane width (1, 4, 8) of the lane kernel
    // (path_lanes.h), which the caller has checked applies to the scene.
    explicit PathIntegrator(int max_depth, int roulette_depth = kDefaultRouletteDepth, int lanes = 0)
        : max_depth_(max_depth), roulette_depth_(roulette_depth), lanes_(lanes) {}
    static const IntegratorInfo& Info();
    const IntegratorInfo& info() const override { return Info(); }
    PathSample Sample(const Scene& scene, const Camera&, const CameraSample& cs, PixelSampler& sampler, SplatFilm&,
                      IntegratorCounters*) const override {
        return Li(scene, cs.ray, sampler, cs.t_min, cs.t_max);
    }
    bool samples_in_batches() const override { return lanes_ > 0; }
    void SampleBatch(const Scene& scene, BatchSample* samples, PathSample* out, size_t n) const override;
    // Radiance arriving along `ray`; max_depth bounds the number of scattering events.
    // [t_min, t_max] limits the first segment (the camera's clipping range).
    PathSample Li(const Scene& scene, Ray ray, PixelSampler& sampler, float t_min = 0.f,
                  float t_max = std::numeric_limits<float>::infinity()) const;

private:
    // The kernel, for shading through BSDF (any scene) or directly with DiffuseBSDF (a
    // scene whose materials are all Lambertian: no variant dispatch per BSDF call). Both
    // compute the same image to the bit on such a scene.
    // kLinks: the scene has light links (light_links.h); a scene without pays nothing for
    // them (the checks compile away).
    template <typename Shading, bool kLinks>
    PathSample Trace(const Scene& scene, Ray ray, PixelSampler& sampler, float t_min, float t_max) const;
    // The kernel for scenes with participating media (path_media.cpp).
    PathSample TraceMedia(const Scene& scene, Ray ray, PixelSampler& sampler, float t_min, float t_max) const;
    int max_depth_;
    int roulette_depth_;
    int lanes_;
};

}  // namespace tessera
