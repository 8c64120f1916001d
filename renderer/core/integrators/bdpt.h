// Bidirectional path tracing (Veach 1997, ch. 10; the lecture's method 10): a camera
// subpath and a light subpath per pixel sample, joined by every (s, t) strategy, s light
// vertices and t camera vertices, weighted by the power heuristic.
//
// Strategies: s = 0 (the camera subpath hits an emitter or escapes to a light at
// infinity), s = 1 (next event estimation from a camera vertex), t = 1 (a light vertex seen
// by the pinhole: splatted anywhere on the frame, as in light tracing), and all others by
// a visibility-tested edge. (s, t) = (1, 1) is not used: light reaching the camera
// unscattered has weight 1 on s = 0. Russian roulette on both subpaths changes only the
// throughputs; MIS weights stay a partition of unity computed from the path alone.
#pragma once

#include "integrator.h"

namespace tessera {

class BDPTIntegrator final : public Integrator {
public:
    explicit BDPTIntegrator(int max_depth) : max_depth_(max_depth) {}
    static const IntegratorInfo& Info();
    const IntegratorInfo& info() const override { return Info(); }
    // The light subpath uses stream 1 of the sample.
    PathSample Sample(const Scene& scene, const Camera& camera, const CameraSample& cs, PixelSampler& sampler,
                      SplatFilm& film, IntegratorCounters* counters) const override {
        PixelSampler light_sampler = cs.Stream(1);
        return SampleStrategies(scene, camera, cs.ray, sampler, light_sampler, film,
                                counters ? &counters->rejected_splats : nullptr, cs.camera_work);
    }

    // One pixel sample: returns the camera-side estimate for the pixel and splats the
    // t = 1 strategies onto `film`. `camera_sampler` and `light_sampler` must be distinct
    // streams of the same pixel sample. Without `camera_work` (a pixel outside a crop) only
    // the t = 1 strategies are made, the same splats bit for bit, and black is returned.
    PathSample SampleStrategies(const Scene& scene, const Camera& camera, const Ray& camera_ray,
                                PixelSampler& camera_sampler, PixelSampler& light_sampler, SplatFilm& film,
                                uint64_t* rejected_splats, bool camera_work = true) const;

private:
    int max_depth_;
};

}  // namespace tessera
