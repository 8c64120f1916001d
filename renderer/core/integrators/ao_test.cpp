// Ambient occlusion against closed forms. A point p on a floor at distance d from a
// perpendicular wall, occluders counted up to distance R: with cosine-weighted directions,
// the hemisphere maps uniformly onto the unit disk (x = sin(theta) cos(phi), toward the
// wall), and a direction is blocked exactly when the wall is nearer than R along it:
// sin(theta) cos(phi) > d / R. The blocked part is the disk's circular segment beyond
// x = a = d / R, so the open fraction is
//     AO = 1 - (acos(a) - a sqrt(1 - a^2)) / pi     (a < 1; 1 otherwise),
// exactly 1/2 for R = infinity (a = 0).
//
// Precision: 64 x 64 pixels x 256 samples, each 0 or 1, give a standard error of at most
// 0.5 / 1024 (0.1 % of 1/2). Each check allows 1 %, so an error of 2 % fails it with a
// margin of ten standard errors; the negative controls prove it by rendering variants off
// by 2 % and requiring that the same check fails.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

#include "integrator.h"
#include "render.h"
#include "scene_helpers.h"

namespace {

using namespace tessera;
using namespace tessera_test;

constexpr double kPi = 3.14159265358979323846;
constexpr float kInf = std::numeric_limits<float>::infinity();

double OpenFraction(double a) { return a >= 1.0 ? 1.0 : 1.0 - (std::acos(a) - a * std::sqrt(1.0 - a * a)) / kPi; }

// The a at which OpenFraction reaches `target` (it increases with a), by bisection.
double SolveOpenFraction(double target) {
    double lo = 0.0, hi = 1.0;
    for (int i = 0; i < 60; ++i) (OpenFraction(0.5 * (lo + hi)) < target ? lo : hi) = 0.5 * (lo + hi);
    return 0.5 * (lo + hi);
}

// A floor (y = 0, half size 1e4) and a wall at x = d facing the origin, from the floor up
// to y = 1e4: at a distance of 1 they are infinite to 1e-4 of the hemisphere.
SceneDesc FloorAndWall(float d) {
    SceneDesc desc = FloorScene(0.5f, 1e4f);
    const uint32_t m = AddMaterial(desc, Color(0.5f), Color(0.f));
    const float s = 1e4f;
    AddQuad(desc, {d, 0, -s}, {d, s, -s}, {d, s, s}, {d, 0, s}, m);
    return desc;
}

// Mean AO over a 64 x 64 image of the floor around the origin.
double MeanAO(const SceneDesc& desc, float max_distance) {
    const Scene scene(desc);
    const Camera camera = LookDownAtOrigin(0.5f, 64);
    RenderOptions opt;
    opt.spp = 256;
    opt.seed = 11;
    opt.threads = 2;
    opt.integrator = "ao";
    if (max_distance != 0.f) opt.integrator_params["max_distance"] = max_distance;
    const std::vector<float> img = Render(scene, camera, opt, {0, 0, 64, 64});
    double sum = 0;
    for (size_t i = 0; i < img.size() / 4; ++i) {
        EXPECT_EQ(img[4 * i + 3], 1.f);                  // every pixel sees the floor
        EXPECT_TRUE(img[4 * i] == img[4 * i + 1] && img[4 * i] == img[4 * i + 2]);  // grey
        sum += img[4 * i];
    }
    return sum / double(img.size() / 4);
}

bool WithinOnePercent(double measured, double expected) { return std::abs(measured / expected - 1.0) <= 0.01; }

TEST(AO, InfiniteWallHidesExactlyHalfTheHemisphere) {
    const double ao = MeanAO(FloorAndWall(1.f), kInf);
    EXPECT_TRUE(WithinOnePercent(ao, 0.5)) << ao;
    // Negative control: a reach at which the closed form is 2 % above 1/2.
    const float reach = float(1.0 / SolveOpenFraction(0.5 * 1.02));
    const double off = MeanAO(FloorAndWall(1.f), reach);
    EXPECT_NEAR(off, 0.51, 0.003);  // the variant is what it should be...
    EXPECT_FALSE(WithinOnePercent(off, 0.5)) << off;  // ...and the check sees it
    std::printf("AO, infinite reach: %.5f (closed form 0.5); control at reach %.2f: %.5f\n", ao, reach, off);
}

TEST(AO, FiniteReachMatchesTheCircularSegment) {
    const double expected = OpenFraction(0.5);  // wall at 1, reach 2: 0.8045
    const double ao = MeanAO(FloorAndWall(1.f), 2.f);
    EXPECT_TRUE(WithinOnePercent(ao, expected)) << ao << " vs " << expected;
    // Negative control: the wall moved nearer until the closed form drops by 2 %.
    const float nearer = float(2.0 * SolveOpenFraction(0.98 * expected));
    const double off = MeanAO(FloorAndWall(nearer), 2.f);
    EXPECT_FALSE(WithinOnePercent(off, expected)) << off << " vs " << expected;
    std::printf("AO, reach 2: %.5f (closed form %.5f); control with the wall at %.4f: %.5f\n", ao, expected,
                nearer, off);
}

TEST(AO, OpenFloorIsWhiteAndTheBackgroundBlack) {
    // Nothing above the floor: every occlusion ray escapes, so every sample is 1 but for
    // the odd direction drawn exactly on the horizon (cos = 0, measure zero), which the
    // surface itself blocks: about one in a million here.
    EXPECT_NEAR(MeanAO(FloorScene(0.5f, 1e4f), kInf), 1.0, 1e-5);
    // The wall beyond the default reach (a tenth of the bounding diameter, here 3000)
    // does not count: an open floor again.
    EXPECT_NEAR(MeanAO(FloorAndWall(5000.f), 0.f), 1.0, 1e-5);
    // Within it, it does (the wall at 100: a = 1/30, closed form 0.5212).
    EXPECT_TRUE(WithinOnePercent(MeanAO(FloorAndWall(100.f), 0.f), OpenFraction(100.0 / 3000.0)));
    // A camera that sees nothing renders black with alpha 0.
    const Scene scene(FloorScene(0.5f));
    const Camera up{{0, 1, 0}, Vec3(1, 0, 0), Vec3(0, 0, -1), Vec3(0, 1, 0), 0.1f, 0.1f, 4, 4};
    RenderOptions opt;
    opt.spp = 4;
    opt.integrator = "ao";
    for (float v : Render(scene, up, opt, {0, 0, 4, 4})) EXPECT_EQ(v, 0.f);
}

TEST(AO, RegistryDescribesItAndRefusesBadSettings) {
    const IntegratorInfo* info = FindIntegrator("ao");
    ASSERT_NE(info, nullptr);
    EXPECT_FALSE(info->splats);
    EXPECT_TRUE(info->stop_per_tile);
    EXPECT_FALSE(info->complete);  // never chosen by auto
    ASSERT_EQ(info->params.size(), 1u);
    EXPECT_EQ(info->params[0].name, "max_distance");
    const Scene scene(FloorScene(0.5f));
    EXPECT_THROW(Integrator::Create("ao", {64, {{"max_distance", -1.f}}}, scene), std::invalid_argument);
    EXPECT_THROW(Integrator::Create("ao", {64, {{"reach", 1.f}}}, scene), std::invalid_argument);
    EXPECT_THROW(Integrator::Create("path", {64, {{"max_distance", 1.f}}}, scene), std::invalid_argument);
    EXPECT_THROW(Integrator::Create("nope", {}, scene), std::invalid_argument);
}

}  // namespace
