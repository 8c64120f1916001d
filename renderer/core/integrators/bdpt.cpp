#include "bdpt.h"

#include <vector>

#include "bdpt_internal.h"

namespace tessera {

using namespace bdpt_internal;

const IntegratorInfo& BDPTIntegrator::Info() {
    static const IntegratorInfo info{
        .name = "bdpt",
        .description = "bidirectional path tracing: every (s, t) strategy, power-heuristic MIS; t = 1 splats",
        .splats = true,
        .stop_per_tile = false,
        .complete = true,
        .delta_caustics = true,
        .traces_light_paths = true,
        .pilot_candidate = IntegratorInfo::PilotCandidate::kAlways,
    };
    return info;
}

IntegratorEntry BDPTIntegratorEntry() {
    return {BDPTIntegrator::Info, [](const IntegratorSettings& s, const Scene&) -> std::unique_ptr<Integrator> {
                return std::make_unique<BDPTIntegrator>(s.max_depth);
            }};
}

PathSample BDPTIntegrator::SampleStrategies(const Scene& scene, const Camera& camera, const Ray& camera_ray,
                                            PixelSampler& camera_sampler, PixelSampler& light_sampler,
                                            SplatFilm& film, uint64_t* rejected_splats, bool camera_work) const {
    // Per-thread vertex storage, reused: no allocation per sample.
    thread_local std::vector<Vertex> camera_path, light_path;
    if (camera_path.size() < size_t(max_depth_) + 2) camera_path.resize(size_t(max_depth_) + 2);
    if (light_path.size() < size_t(max_depth_) + 1) light_path.resize(size_t(max_depth_) + 1);

    Walker walker(scene, camera, max_depth_);
    PathSample result;
    const int n_camera = CameraSubpathFor(walker, camera, camera_ray, camera_sampler, camera_path.data(), camera_work);
    const int n_light = walker.LightSubpath(light_sampler, light_path.data());
    if (n_camera > 1 && camera_path[1].type == VertexType::kSurface) result.alpha = 1.f;

    Color L(0.f);
    Vertex sampled;  // the strategy's own endpoint (s = 1 or t = 1), set by Connect
    for (int t = 1; t <= (camera_work ? n_camera : 1); ++t) {
        for (int s = 0; s <= n_light; ++s) {
            const int depth = t + s - 2;
            if ((s == 1 && t == 1) || depth < 0 || depth > max_depth_) continue;
            float px = 0.f, py = 0.f;
            Color c = walker.Connect(light_path.data(), camera_path.data(), s, t, camera_sampler, &sampled, &px, &py);
            if (IsBlack(c)) continue;
            c *= walker.MISWeight(light_path.data(), camera_path.data(), sampled, s, t);
            if (t == 1) {
                if (!film.Add(px, py, c) && rejected_splats) ++*rejected_splats;
            } else {
                L += c;
            }
        }
    }
    result.radiance = L;
    return result;
}

}  // namespace tessera
