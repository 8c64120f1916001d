// vcm against closed forms, and its scene pass's contract.
//
// Statistics: every iteration draws fresh light paths (the scene pass) and fresh camera
// samples (its own sample range), so the per-iteration image means are independent; their
// mean and standard error over K iterations give the estimate and its precision. Each
// check allows 4 standard errors, requires the standard error to be at most 0.4 % of the
// expected value (so the check detects 2 %: 2 % > 4 x 0.4 % + margin), and proves it with a
// negative control: the same check against the closed form times 1.02 must fail.
//
// The merging radius is small against the scenes' features (the kernel's bias is below
// 1e-4 of the value: for a point light at height h, 3/4 (r/h)^2), so the closed forms are
// those of the exact transport.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "integrator.h"
#include "render.h"
#include "scene_helpers.h"

namespace {

using namespace tessera;
using namespace tessera_test;

using Estimate = ChannelEstimate;

// Per-iteration means over the image, K iterations of `spp` samples each.
Estimate IterationMeans(const Scene& scene, const Camera& camera, RenderOptions opt, int iterations) {
    std::vector<std::array<double, 3>> per(iterations);
    const uint32_t spp = opt.spp;
    for (int k = 0; k < iterations; ++k) {
        opt.sample_start = uint32_t(k) * spp;
        opt.scene_product = RunScenePass(scene, opt, uint32_t(k));
        const std::vector<float> img = RenderResolved(scene, camera, opt);
        for (int c = 0; c < 3; ++c) per[k][c] = MeanChannel(img, c);
    }
    return MeanAndStandardError(per);
}

bool Agrees(const Estimate& e, int c, double expected) {
    return std::abs(e.mean[c] - expected) <= 4.0 * e.stderr_mean[c] + 1e-4 * expected;
}

void ExpectClosedForm(const Estimate& e, int c, double expected, const char* what) {
    EXPECT_TRUE(Agrees(e, c, expected)) << what << " channel " << c << ": " << e.mean[c] << " +- "
                                         << e.stderr_mean[c] << " vs " << expected;
    EXPECT_GT(e.stderr_mean[c], 0.0) << what;  // noise exists: the tolerance is not vacuous
    EXPECT_LT(e.stderr_mean[c], 0.004 * expected) << what;
    EXPECT_FALSE(Agrees(e, c, 1.02 * expected)) << what << ": a 2 % error would pass";
    std::printf("vcm %s, channel %d: %.5f +- %.5f (closed form %.5f, %+.2f %%)\n", what, c, e.mean[c],
                e.stderr_mean[c], expected, 100.0 * (e.mean[c] / expected - 1.0));
}

RenderOptions VCMOptions(uint32_t spp, float light_paths, float radius) {
    RenderOptions opt;
    opt.spp = spp;
    opt.seed = 7;
    opt.threads = 2;
    opt.integrator = "vcm";
    // Iterations of equal samples (IterationMeans): one batch of light paths each.
    opt.integrator_params = {{"light_paths", light_paths}, {"radius", radius}, {"grow", 0.f}};
    return opt;
}

// A closed Lambertian box, every wall of albedo a emitting Le: radiance Le / (1 - a)
// everywhere, carried by paths of every length, so every strategy (each connection and
// each merging) contributes and the MIS weights must sum to one at every depth.
TEST(VCM, LambertianFurnaceIsLeOverOneMinusAlbedo) {
    const float a = 0.5f;
    const Color Le(0.5f, 1.f, 2.f);
    SceneDesc d;
    AddInwardBox(d, {-1, -2, -1.5f}, {3, 1, 2}, AddMaterial(d, Color(a), Le, true));
    const Scene scene(d);
    RenderOptions opt = VCMOptions(2, 20000.f, 0.03f);
    opt.max_depth = 100;
    const Estimate e = IterationMeans(scene, LookDownMinusZ({0.2f, -0.3f, 0.1f}, 16, 16, 1.2f), opt, 24);
    for (int c = 0; c < 3; ++c) ExpectClosedForm(e, c, Le[c] / (1.0 - a), "furnace");
}

// A point light of intensity I at height h over a Lambertian floor of albedo a, seen
// straight down through a square of half-width s on the floor (a pinhole parallel to the
// floor maps pixels to equal floor areas): the image's mean is a / pi times the mean
// irradiance over the square, I Omega / (4 s^2), with Omega = 4 atan(s^2 / (h sqrt(h^2 +
// 2 s^2))) the solid angle the square subtends at the light. Delta light: no s = 0; the
// floor is lit by NEE, light tracing and merging, which share it.
TEST(VCM, PointLitFloorMatchesTheInverseSquareLaw) {
    const double h = 1.0, albedo = 0.5, intensity = 2.0, cam_height = 0.5, tan_half = 1.0;
    SceneDesc d = FloorScene(float(albedo), 1000.f);
    d.point_lights.push_back({{0.f, float(h), 0.f}, Color(float(intensity))});
    const Scene scene(d);
    RenderOptions opt = VCMOptions(4, 100000.f, 0.02f);
    opt.max_depth = 4;
    const Camera camera{{0, float(cam_height), 0}, Vec3(1, 0, 0), Vec3(0, 0, -1), Vec3(0, -1, 0),
                        float(tan_half), float(tan_half), 16, 16};
    const Estimate e = IterationMeans(scene, camera, opt, 24);
    const double s = tan_half * cam_height;
    const double omega = 4.0 * std::atan(s * s / (h * std::sqrt(h * h + 2.0 * s * s)));
    ExpectClosedForm(e, 0, albedo / kPi * intensity * omega / (4.0 * s * s), "point-lit floor");
}

// Clear glass as a slab in front of an emitter, at normal incidence (as in test_render.cpp):
// T = (1 - R) / (1 + R) with R = ((n - 1) / (n + 1))^2. Only specular chains: nothing
// merges, and the estimate is bdpt's.
TEST(VCM, GlassSlabTransmitsOneMinusROverOnePlusR) {
    MaterialParams glass;
    glass.opacity = 0.f;
    glass.roughness = 0.f;
    glass.ior = 1.5f;
    SceneDesc d;
    d.materials.push_back({glass.diffuse_color, Color(0.f), false, glass});
    const uint32_t g = uint32_t(d.materials.size() - 1);
    AddQuad(d, {-50, -50, -1}, {50, -50, -1}, {50, 50, -1}, {-50, 50, -1}, g);
    AddQuad(d, {-50, -50, -1.2f}, {-50, 50, -1.2f}, {50, 50, -1.2f}, {50, -50, -1.2f}, g);
    AddQuad(d, {-500, -500, -5}, {500, -500, -5}, {500, 500, -5}, {-500, 500, -5}, AddMaterial(d, Color(0.f), Color(2.f)));
    const Scene scene(d);
    RenderOptions opt = VCMOptions(16, 20000.f, 0.05f);
    const Estimate e = IterationMeans(scene, LookDownMinusZ({0, 0, 0}, 16, 16, 1e-4f), opt, 16);
    const double R = 0.04;
    // Every path is the same specular chain: the estimate has no noise but that of the
    // chain's length under Russian roulette, so only the value is checked here.
    EXPECT_NEAR(e.mean[0], 2.0 * (1 - R) / (1 + R), 5 * e.stderr_mean[0] + 2e-3) << e.mean[0];
    EXPECT_GT(std::abs(e.mean[0] - 1.02 * 2.0 * (1 - R) / (1 + R)), 5 * e.stderr_mean[0] + 2e-3);
}

TEST(VCM, TheProductIsAPureFunctionOfSeedAndIteration) {
    SceneDesc d = FloorScene(0.5f, 10.f);
    d.point_lights.push_back({{0.f, 1.f, 0.f}, Color(1.f)});
    const Scene scene(d);
    RenderOptions opt = VCMOptions(1, 5000.f, 0.1f);
    // Merging direct light too, so that the floor's vertices are stored.
    opt.integrator_params["direct_merging"] = 1.f;
    const std::string a = RunScenePass(scene, opt, 3);
    opt.threads = 1;
    EXPECT_EQ(RunScenePass(scene, opt, 3), a);  // the thread count only decides who computes it
    EXPECT_NE(RunScenePass(scene, opt, 4), a);  // every iteration draws fresh light paths
    opt.seed += 1;
    EXPECT_NE(RunScenePass(scene, opt, 3), a);
    // About half the paths go down and land on the floor (the rest escape): one vertex each.
    EXPECT_GT(a.size(), 2000u * 56u);
    EXPECT_LT(a.size(), 3000u * 56u + 20000u * 4u);
    // By default direct light is not merged, and the floor is all there is to hit: no
    // vertex is stored.
    opt.integrator_params["direct_merging"] = 0.f;
    EXPECT_LT(RunScenePass(scene, opt, 3).size(), 64u + 20000u * 4u);
    // Without merging there is nothing to store.
    opt.integrator_params["merging"] = 0.f;
    EXPECT_LT(RunScenePass(scene, opt, 3).size(), 64u);
}

TEST(VCM, TilesRefuseAForeignProductAndBadSettings) {
    SceneDesc d = FloorScene(0.5f, 10.f);
    d.point_lights.push_back({{0.f, 1.f, 0.f}, Color(1.f)});
    const Scene scene(d);
    const Camera camera = LookDownAtOrigin(0.5f, 4);
    RenderOptions opt = VCMOptions(1, 5000.f, 0.1f);
    std::vector<float> out(64);
    std::vector<int64_t> splats(48);
    EXPECT_THROW(RenderTile(scene, camera, opt, {0, 0, 4, 4}, out.data(), nullptr, splats.data()),
                 std::invalid_argument);
    opt.scene_product = "not a light-vertex grid";
    EXPECT_THROW(RenderTile(scene, camera, opt, {0, 0, 4, 4}, out.data(), nullptr, splats.data()),
                 std::invalid_argument);
    opt.scene_product = RunScenePass(scene, opt, 0);
    opt.integrator_params["light_paths"] = 6000.f;  // a product of other settings
    EXPECT_THROW(RenderTile(scene, camera, opt, {0, 0, 4, 4}, out.data(), nullptr, splats.data()),
                 std::invalid_argument);
    for (auto [name, value] : std::vector<std::pair<std::string, float>>{
             {"alpha", 1.f}, {"alpha", 0.f}, {"radius", -1.f}, {"light_paths", 0.5f}, {"merging", 2.f},
             {"direct_merging", 0.5f}})
        EXPECT_THROW(Integrator::Create("vcm", {64, {{name, value}}}, scene), std::invalid_argument) << name;
    const IntegratorInfo* info = FindIntegrator("vcm");
    ASSERT_NE(info, nullptr);
    EXPECT_TRUE(info->scene_passes && info->splats && info->delta_caustics);
    EXPECT_FALSE(info->stop_per_tile);
}

}  // namespace
