// photon_direct against a closed form, and its scene pass's contract (a pure function of
// scene, settings, seed and iteration; refused products).
//
// A point light of intensity I at height h above a Lambertian floor of albedo a: the
// irradiance at distance rho from the foot of the light is E = I h / (h^2 + rho^2)^{3/2},
// so the disk kernel of radius r estimates the mean irradiance over the disk,
//     E_r = (2 I / r^2) (1 - h / sqrt(h^2 + r^2)),
// and the floor under the light has radiance L = (a / pi) E_r (the kernel's bias is in the
// closed form, so the check is of the estimator, not of its limit).
//
// Precision: 16 iterations of batches of 10^6 photons (30 batches: from the third
// iteration on each holds two, the most 2e6 photons allow); about 1.5 % of the photons land
// in the disk (the solid angle it subtends over 4 pi), 4.5e5 in all, so the Poisson bound
// on the relative error is 0.15 % (measured over 40 one-batch iterations: -0.11 %). The check allows 1 %, so
// an error of 2 % fails it by more than three standard errors; the negative control
// proves it with a light 2 % brighter checked against the unchanged closed form.
#include <gtest/gtest.h>

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

constexpr double kPi = 3.14159265358979323846;
constexpr float kHeight = 1.f, kRadius = 0.25f, kAlbedo = 0.5f;

double ClosedForm(double intensity) {
    const double h = kHeight, r = kRadius;
    return kAlbedo / kPi * (2.0 * intensity / (r * r)) * (1.0 - h / std::sqrt(h * h + r * r));
}

SceneDesc PointLitFloor(float intensity) {
    SceneDesc desc = FloorScene(kAlbedo, 1000.f);
    desc.point_lights.push_back({{0.f, kHeight, 0.f}, Color(intensity)});
    return desc;
}

RenderOptions Options() {
    RenderOptions opt;
    opt.spp = 1;
    opt.seed = 5;
    opt.threads = 2;
    opt.integrator = "photon_direct";
    opt.integrator_params = {{"photons", 1e6f}, {"radius", kRadius}};
    return opt;
}

// The floor's radiance under the light, averaged over `iterations` independent photon maps.
double MeanRadiance(const Scene& scene, int iterations) {
    const Camera camera = LookDownAtOrigin(0.5f, 4);
    RenderOptions opt = Options();
    double sum = 0;
    for (int k = 0; k < iterations; ++k) {
        opt.scene_product = RunScenePass(scene, opt, uint32_t(k));
        const std::vector<float> img = Render(scene, camera, opt, {0, 0, 4, 4});
        for (size_t i = 0; i < 16; ++i) {
            EXPECT_EQ(img[4 * i + 3], 1.f);
            sum += img[4 * i];
        }
    }
    return sum / (16.0 * iterations);
}

bool WithinOnePercent(double measured, double expected) { return std::abs(measured / expected - 1.0) <= 0.01; }

TEST(PhotonDirect, PointLitFloorMatchesTheKernelsClosedForm) {
    const double expected = ClosedForm(1.0);
    const double measured = MeanRadiance(Scene(PointLitFloor(1.f)), 16);
    EXPECT_TRUE(WithinOnePercent(measured, expected)) << measured << " vs " << expected;
    // Negative control: a light 2 % brighter must fail the same check.
    const double off = MeanRadiance(Scene(PointLitFloor(1.02f)), 16);
    EXPECT_FALSE(WithinOnePercent(off, expected)) << off << " vs " << expected;
    std::printf("photon_direct under a point light: %.5f (closed form %.5f, %+.2f %%); control +2 %%: %.5f\n",
                measured, expected, 100.0 * (measured / expected - 1.0), off);
}

TEST(PhotonDirect, TheProductIsAPureFunctionOfSeedAndIteration) {
    const Scene scene(PointLitFloor(1.f));
    RenderOptions opt = Options();
    opt.integrator_params["photons"] = 20000.f;
    const std::string a = RunScenePass(scene, opt, 3);
    opt.threads = 1;
    EXPECT_EQ(RunScenePass(scene, opt, 3), a);  // the thread count only decides who computes it
    EXPECT_NE(RunScenePass(scene, opt, 4), a);  // every iteration draws fresh photons
    opt.seed += 1;
    EXPECT_NE(RunScenePass(scene, opt, 3), a);
    // Iteration 3 holds 4 batches of 20000 (IterationBatches: passes of 1, 1, 2, 4 samples),
    // and half the photons of a point light go up and escape: about half are kept.
    EXPECT_GT(a.size(), 36000u * 40u);
    EXPECT_LT(a.size(), 44000u * 40u + 64u);
    // Iteration 0 holds one batch.
    const std::string first = RunScenePass(scene, opt, 0);
    EXPECT_GT(first.size(), 9000u * 40u);
    EXPECT_LT(first.size(), 11000u * 40u + 64u);
}

TEST(PhotonDirect, TilesRefuseAMissingOrForeignProduct) {
    const Scene scene(PointLitFloor(1.f));
    const Camera camera = LookDownAtOrigin(0.5f, 4);
    RenderOptions opt = Options();
    std::vector<float> out(64);
    EXPECT_THROW(RenderTile(scene, camera, opt, {0, 0, 4, 4}, out.data()), std::invalid_argument);
    opt.scene_product = "not a photon map";
    EXPECT_THROW(RenderTile(scene, camera, opt, {0, 0, 4, 4}, out.data()), std::invalid_argument);
    // An integrator without scene passes has none to run.
    RenderOptions path;
    EXPECT_THROW(RunScenePass(scene, path, 0), std::invalid_argument);
}

TEST(PhotonDirect, RegistryDescribesIt) {
    const IntegratorInfo* info = FindIntegrator("photon_direct");
    ASSERT_NE(info, nullptr);
    EXPECT_TRUE(info->scene_passes);
    EXPECT_FALSE(info->stop_per_tile);
    EXPECT_FALSE(info->splats);
    EXPECT_FALSE(info->complete);
    const Scene scene(PointLitFloor(1.f));
    EXPECT_THROW(Integrator::Create("photon_direct", {64, {{"radius", -1.f}}}, scene), std::invalid_argument);
    EXPECT_THROW(Integrator::Create("photon_direct", {64, {{"photons", 0.5f}}}, scene), std::invalid_argument);
}

}  // namespace
