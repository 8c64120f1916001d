// Scenes and column statistics shared by the motion-blur tests (scene/motion_test.cpp,
// scene/motion_lights_test.cpp, scene/motion_passes_test.cpp): an emitting quad that slides
// or deforms across a 16 x 16 orthographic view, per-column means over K seeds, and the
// one-sample and Welch t-tests of those columns against a closed form or a reference.
#pragma once

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include "scene_helpers.h"

namespace motion_scenes {

using namespace tessera;
using namespace tessera_test;

constexpr uint32_t kW = 16, kH = 16;

// Row-major 3x4 translation.
inline std::vector<float> Translation(float x, float y, float z) { return {1, 0, 0, x, 0, 1, 0, y, 0, 0, 1, z}; }

// An emitting unit-wide quad x in [0, 1], y in [-1, 1] at depth z = -3, facing the camera
// at the origin, translated in x from x0 (shutter open) to x0 + distance (shutter close);
// a black backdrop behind it. With distance 0 and x0 = x it is the static scene.
inline SceneDesc SlidingEmitter(float le, float x0, float distance) {
    SceneDesc d;
    const uint32_t black = AddMaterial(d, Color(0.f), Color(0.f));
    const uint32_t emitter = AddMaterial(d, Color(0.f), Color(le));
    AddQuad(d, {-50, -50, -6}, {50, -50, -6}, {50, 50, -6}, {-50, 50, -6}, black);
    MeshDesc quad;
    quad.positions = {0, -1, -3, 1, -1, -3, 1, 1, -3, 0, 1, -3};
    quad.indices = {0, 1, 2, 0, 2, 3};
    quad.triangle_material = {emitter, emitter};
    d.prototypes.push_back(quad);
    d.instance_prototype = {0};
    d.instance_transforms = Translation(x0, 0, 0);
    if (distance != 0.f) {
        d.motion_instances = {0};
        d.motion_time_steps = {2};
        d.motion_transforms = Translation(x0, 0, 0);
        const std::vector<float> close = Translation(x0 + distance, 0, 0);
        d.motion_transforms.insert(d.motion_transforms.end(), close.begin(), close.end());
    }
    return d;
}

// An emitting quad y in [-1, 1] at z = -3 whose left edge runs from x = l0 to l1 and right
// edge from r0 to r1 over the shutter: a deforming prototype (vertex time steps), placed
// by a still instance. l0 = l1 = x0, r0 = r1 = x0 + 1: the still quad.
inline SceneDesc DeformingEmitter(float le, float l0, float l1, float r0, float r1) {
    SceneDesc d = SlidingEmitter(le, 0.f, 0.f);
    MeshDesc& quad = d.prototypes[0];
    quad.positions = {l0, -1, -3, r0, -1, -3, r0, 1, -3, l0, 1, -3};
    if (l0 != l1 || r0 != r1) quad.motion_positions = {l1, -1, -3, r1, -1, -3, r1, 1, -3, l1, 1, -3};
    return d;
}
// An orthographic view 4 units wide: column c sees x in [-2 + c / 4, -2 + (c + 1) / 4].
inline Camera OrthoView() {
    Camera cam = LookDownMinusZ({0, 0, 0}, kW, kH, 2.f);
    cam.projection = Projection::kOrthographic;
    return cam;
}

// Per-column means of rows [y0, y1) over K renders with seeds opt.seed + k: the mean and
// the variance of the K per-run values.
struct Profile {
    std::vector<double> mean, var;
};
inline Profile ColumnProfile(const std::function<std::vector<float>(uint32_t seed)>& render, uint32_t seed, int K,
                      uint32_t y0, uint32_t y1, int channel = 0) {
    std::vector<std::vector<double>> runs;
    for (int k = 0; k < K; ++k) {
        const std::vector<float> img = render(seed + uint32_t(k));
        std::vector<double> cols(kW, 0.0);
        for (uint32_t y = y0; y < y1; ++y)
            for (uint32_t x = 0; x < kW; ++x) cols[x] += img[4 * (kW * y + x) + channel] / double(y1 - y0);
        runs.push_back(cols);
    }
    Profile p{std::vector<double>(kW, 0.0), std::vector<double>(kW, 0.0)};
    for (uint32_t x = 0; x < kW; ++x) {
        for (int k = 0; k < K; ++k) p.mean[x] += runs[k][x] / K;
        for (int k = 0; k < K; ++k) p.var[x] += (runs[k][x] - p.mean[x]) * (runs[k][x] - p.mean[x]) / (K - 1);
    }
    return p;
}

// Columns of `p` (scaled by `scale`, shifted by `offset`) outside the one-sample t-test
// limit (K - 1 degrees of freedom) around the known `expected`; with `report`, each is
// reported and every column's limit must be at most `resolution`.
inline int FailingColumns(const Profile& p, double scale, double offset, const std::vector<double>& expected, int K,
                   double critical, double resolution, const std::string& what, bool report) {
    int failing = 0;
    for (uint32_t x = 0; x < kW; ++x) {
        const double se = std::sqrt(p.var[x] / K) * scale, value = scale * p.mean[x] + offset;
        if (report) EXPECT_LE(critical * se, resolution) << what << ": column " << x << " too noisy";
        if (std::abs(value - expected[x]) > std::max(critical * se, 1e-6)) {
            ++failing;
            if (report)
                ADD_FAILURE() << what << ": column " << x << " = " << value << ", expected " << expected[x] << " +- "
                              << critical * se;
        }
    }
    return failing;
}

inline std::vector<float> RenderWith(const Scene& scene, const Camera& cam, RenderOptions o, const char* integrator,
                              uint32_t seed) {
    o.integrator = integrator;
    o.seed = seed;
    const IntegratorInfo* info = FindIntegrator(integrator);
    if (info && info->scene_passes) o.scene_product = RunScenePass(scene, o, 0);
    return RenderResolved(scene, cam, o);
}

// Columns where `p` (scaled by `scale`, shifted by `offset`; K runs) and `ref` (K runs)
// differ by Welch's t beyond the two-sided limit at `alpha`. With `report`, each failing
// column is reported as `what` and every column's limit must be at most `resolution`, so
// that a control perturbed by more than twice that must fail.
inline int WelchFailingColumns(const Profile& p, double scale, double offset, const Profile& ref, int K, double alpha,
                        double resolution, const std::string& what, bool report) {
    int failing = 0;
    for (uint32_t x = 0; x < kW; ++x) {
        const double value = scale * p.mean[x] + offset;
        const Welch w = WelchT(value, scale * scale * p.var[x], K, ref.mean[x], ref.var[x], K);
        const double critical = StudentTCritical(alpha, w.df);
        if (report) EXPECT_LE(critical * w.se, resolution) << what << ": column " << x << " too noisy";
        if (std::abs(w.t) > critical && std::abs(value - ref.mean[x]) > 1e-6) {
            ++failing;
            if (report)
                ADD_FAILURE() << what << ": column " << x << " = " << value << ", reference " << ref.mean[x]
                              << " (t = " << w.t << ")";
        }
    }
    return failing;
}

}  // namespace motion_scenes
