#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <limits>
#include <vector>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "chi_square.h"
#include "render.h"
#include "splat_film.h"
#include "scene.h"
#include "scene_helpers.h"

using namespace tessera;
using namespace tessera_test;

namespace {

// A small Cornell-like box: white walls, red and green sides, a ceiling light, a block.
SceneDesc SmallCornell() {
    SceneDesc d;
    uint32_t white = AddMaterial(d, Color(0.73f, 0.71f, 0.68f), Color(0.f));
    uint32_t red = AddMaterial(d, Color(0.63f, 0.065f, 0.05f), Color(0.f));
    uint32_t green = AddMaterial(d, Color(0.14f, 0.45f, 0.09f), Color(0.f));
    uint32_t light = AddMaterial(d, Color(0.78f), Color(17.f, 12.f, 4.f));
    AddQuad(d, {-1, -1, -1}, {1, -1, -1}, {1, -1, -3}, {-1, -1, -3}, white);  // floor
    AddQuad(d, {-1, 1, -1}, {-1, 1, -3}, {1, 1, -3}, {1, 1, -1}, white);      // ceiling
    AddQuad(d, {-1, -1, -3}, {1, -1, -3}, {1, 1, -3}, {-1, 1, -3}, white);    // back
    AddQuad(d, {-1, -1, -1}, {-1, -1, -3}, {-1, 1, -3}, {-1, 1, -1}, red);    // left
    AddQuad(d, {1, -1, -1}, {1, 1, -1}, {1, 1, -3}, {1, -1, -3}, green);      // right
    AddQuad(d, {-0.3f, 0.99f, -1.7f}, {-0.3f, 0.99f, -2.3f}, {0.3f, 0.99f, -2.3f}, {0.3f, 0.99f, -1.7f}, light);
    AddQuad(d, {-0.6f, -0.2f, -2.2f}, {0.f, -0.2f, -2.4f}, {0.1f, -0.2f, -1.9f}, {-0.5f, -0.2f, -1.7f}, white);
    return d;
}

}  // namespace

TEST(Render, EmitterSeenDirectlyIsExactlyItsRadiance) {
    SceneDesc d;
    uint32_t m = AddMaterial(d, Color(0.f), Color(0.3f, 2.f, 17.5f));
    AddQuad(d, {-100, -100, -1}, {100, -100, -1}, {100, 100, -1}, {-100, 100, -1}, m);  // faces +z, the camera
    Scene scene(d);
    Camera cam = LookDownMinusZ({0, 0, 0}, 8, 6);
    auto px = Render(scene, cam, {16, 1, 8, 2}, {0, 0, 8, 6});
    for (size_t i = 0; i < 8 * 6; ++i) {
        EXPECT_EQ(px[4 * i + 0], 0.3f);
        EXPECT_EQ(px[4 * i + 1], 2.f);
        EXPECT_EQ(px[4 * i + 2], 17.5f);
        EXPECT_EQ(px[4 * i + 3], 1.f);
    }
    // The same one-sided emitter seen from behind emits nothing.
    Camera behind{{0, 0, -2}, Vec3(-1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1), 0.5f, 0.375f, 8, 6};
    auto back = Render(scene, behind, {16, 1, 8, 2}, {0, 0, 8, 6});
    for (size_t i = 0; i < 8 * 6; ++i) EXPECT_EQ(back[4 * i + 0] + back[4 * i + 1] + back[4 * i + 2], 0.f);
}

TEST(Render, SphereLightSeenDirectlyIsExactlyItsRadiance) {
    SceneDesc d;
    d.sphere_lights.push_back({Vec3(0, 0, -10), 5.f, Color(1.5f, 0.25f, 4.f)});
    Scene scene(d);
    auto px = Render(scene, LookDownMinusZ({0, 0, 0}, 4, 4, 0.1f), {8, 3, 4, 1}, {0, 0, 4, 4});
    for (size_t i = 0; i < 16; ++i) {
        EXPECT_EQ(px[4 * i + 0], 1.5f);
        EXPECT_EQ(px[4 * i + 2], 4.f);
    }
}

TEST(Render, PixelsDoNotDependOnTilesOrThreads) {
    Scene scene(SmallCornell());
    const uint32_t W = 37, H = 23;
    Camera cam = LookDownMinusZ({0, 0, 1.5f}, W, H, 0.45f);
    RenderOptions opt{6, 42, 16, 2};
    auto whole = Render(scene, cam, opt, {0, 0, W, H});

    // 7 x 5 tiles of uneven sizes, rendered in reverse order with one thread.
    const uint32_t xs[8] = {0, 3, 9, 10, 18, 25, 31, W};
    const uint32_t ys[6] = {0, 1, 7, 12, 20, H};
    std::vector<float> tiled(whole.size(), -1.f);
    opt.threads = 1;
    for (int ty = 4; ty >= 0; --ty)
        for (int tx = 6; tx >= 0; --tx) {
            TileRect t{xs[tx], ys[ty], xs[tx + 1] - xs[tx], ys[ty + 1] - ys[ty]};
            auto px = Render(scene, cam, opt, t);
            for (uint32_t y = 0; y < t.height; ++y)
                std::memcpy(&tiled[4 * (size_t(t.y0 + y) * W + t.x0)], &px[4 * size_t(y) * t.width],
                            4 * t.width * sizeof(float));
        }
    ASSERT_EQ(0, std::memcmp(whole.data(), tiled.data(), whole.size() * sizeof(float)));
    // And the image is not trivially black.
    double sum = 0;
    for (float v : whole) sum += v;
    EXPECT_GT(sum, 1.0);
}

// PathIntegrator shades an all-Lambertian scene with DiffuseBSDF directly (its specialised
// kernel); any UsdPreviewSurface in the scene, even one no triangle uses, sends it through
// BSDF's variant instead. The two kernels must be the same computation.
TEST(Render, LambertianKernelIsTheGeneralKernelBitForBit) {
    const SceneDesc lambert = SmallCornell();
    SceneDesc general = lambert;
    general.materials.push_back({Color(0.5f), Color(0.f), false, MaterialParams{}});  // used by no triangle
    const Scene a(lambert), b(general);
    ASSERT_TRUE(a.all_lambertian());
    ASSERT_FALSE(b.all_lambertian());
    const uint32_t W = 24, H = 16;
    const Camera cam = LookDownMinusZ({0, 0, 1.5f}, W, H, 0.45f);
    const RenderOptions opt{16, 7, 8, 2};
    const auto fast = Render(a, cam, opt, {0, 0, W, H});
    const auto slow = Render(b, cam, opt, {0, 0, W, H});
    ASSERT_EQ(0, std::memcmp(fast.data(), slow.data(), fast.size() * sizeof(float)));
    // The control: the comparison tells a 1 % darker wall apart.
    SceneDesc darker = general;
    darker.materials[1].albedo = darker.materials[1].albedo * 0.99f;
    const auto other = Render(Scene(darker), cam, opt, {0, 0, W, H});
    EXPECT_NE(0, std::memcmp(fast.data(), other.data(), fast.size() * sizeof(float)));
}

// A UsdPreviewSurface that equals a Lambertian exactly (specularColor 0 in the specular
// workflow, as exporters write plain diffuse materials) is rendered as one: the scene keeps
// the Lambertian kernel and the image is the Lambertian scene's, bit for bit.
TEST(Render, ExactlyLambertianPreviewSurfacesKeepTheLambertianKernel) {
    const SceneDesc lambert = SmallCornell();
    auto as_exported = [&](Color specular) {
        SceneDesc d = lambert;
        for (Material& m : d.materials) {
            MaterialParams p;
            p.diffuse_color = m.albedo;
            p.emissive_color = m.emission;
            p.roughness = 1.f;
            p.use_specular_workflow = true;
            p.specular_color = specular;
            m.preview = p;
        }
        return d;
    };
    const Scene a(lambert), b(as_exported(Color(0.f)));
    ASSERT_TRUE(b.all_lambertian());
    const uint32_t W = 24, H = 16;
    const Camera cam = LookDownMinusZ({0, 0, 1.5f}, W, H, 0.45f);
    const RenderOptions opt{16, 7, 8, 2};
    const auto want = Render(a, cam, opt, {0, 0, W, H});
    const auto got = Render(b, cam, opt, {0, 0, W, H});
    ASSERT_EQ(0, std::memcmp(want.data(), got.data(), want.size() * sizeof(float)));
    // The control: a specular colour of 0.001 is a real (faint) lobe, not a Lambertian.
    const Scene c(as_exported(Color(1e-3f, 0.f, 0.f)));
    EXPECT_FALSE(c.all_lambertian());
    const auto other = Render(c, cam, opt, {0, 0, W, H});
    EXPECT_NE(0, std::memcmp(want.data(), other.data(), want.size() * sizeof(float)));
}

TEST(Render, SeedChangesNoiseOnly) {
    Scene scene(SmallCornell());
    Camera cam = LookDownMinusZ({0, 0, 1.5f}, 16, 16, 0.45f);
    auto a = Render(scene, cam, {4, 1, 16, 2}, {0, 0, 16, 16});
    auto b = Render(scene, cam, {4, 2, 16, 2}, {0, 0, 16, 16});
    EXPECT_NE(0, std::memcmp(a.data(), b.data(), a.size() * sizeof(float)));
}

// White furnace: inside a closed box whose walls all have albedo a and emit Le (both
// sides), radiance everywhere is Le (1 + a + a^2 + ...) = Le / (1 - a).
class Furnace : public ::testing::TestWithParam<float> {};

TEST_P(Furnace, EveryPixelIsLeOverOneMinusAlbedo) {
    const float a = GetParam();
    const Color Le(0.5f, 1.f, 2.f);
    SceneDesc d;
    AddInwardBox(d, {-1, -2, -1.5f}, {3, 1, 2}, AddMaterial(d, Color(a), Le, true));
    Scene scene(d);
    const uint32_t W = 32, H = 32;
    auto px = Render(scene, LookDownMinusZ({0.2f, -0.3f, 0.1f}, W, H, 1.2f), {64, 9, 100000, 2}, {0, 0, W, H});
    for (int c = 0; c < 3; ++c) {
        double expected = Le[c] / (1.0 - a);
        double sum = 0, sum2 = 0;
        for (size_t i = 0; i < W * H; ++i) {
            sum += px[4 * i + c];
            sum2 += double(px[4 * i + c]) * px[4 * i + c];
        }
        double n = W * H, mean = sum / n;
        double stderr_mean = std::sqrt(std::max(0.0, sum2 / n - mean * mean) / n);
        EXPECT_NEAR(mean, expected, 5.0 * stderr_mean + 1e-5 * expected) << "channel " << c << " albedo " << a;
        EXPECT_GT(stderr_mean, 0.0);  // noise exists, so the tolerance is not vacuous
        EXPECT_LT(stderr_mean, 0.01 * expected);
    }
}

INSTANTIATE_TEST_SUITE_P(Albedo, Furnace, ::testing::Values(0.5f, 0.9f));

TEST(Scene, RejectsBadInputWithAClearError) {
    SceneDesc d = SmallCornell();
    d.indices[4] = 100000;
    EXPECT_THROW(Scene{d}, std::invalid_argument);
    d = SmallCornell();
    d.positions[7] = NAN;
    EXPECT_THROW(Scene{d}, std::invalid_argument);
    d = SmallCornell();
    d.triangle_material[0] = 99;
    EXPECT_THROW(Scene{d}, std::invalid_argument);
    d = SmallCornell();
    d.materials[0].albedo = Color(1.5f);
    EXPECT_THROW(Scene{d}, std::invalid_argument);
    d = SmallCornell();
    d.materials[3].emission = Color(-1.f);
    EXPECT_THROW(Scene{d}, std::invalid_argument);
}

TEST(Scene, EmptySceneRendersBlack) {
    Scene scene(SceneDesc{});
    auto px = Render(scene, LookDownMinusZ({0, 0, 0}, 4, 4), {2, 0, 8, 1}, {0, 0, 4, 4});
    for (float v : px) EXPECT_EQ(v, 0.f);
}

TEST(Lights, PointLightFollowsTheInverseSquareAndCosineLaws) {
    // Reflected radiance of a Lambertian floor: a/pi * I cos(theta) / d^2.
    SceneDesc d = FloorScene(0.6f);
    d.point_lights.push_back({Vec3(3, 4, 0), Color(10.f, 20.f, 5.f)});  // d = 5, cos = 4/5
    Scene scene(d);
    auto px = Render(scene, LookDownAtOrigin(1.f), {4, 0, 1, 1}, {0, 0, 4, 4});
    const double geometry = 0.6 / kPi * 0.8 / 25.0;
    EXPECT_NEAR(MeanChannel(px, 0), 10.0 * geometry, 1e-4 * 10.0 * geometry);
    EXPECT_NEAR(MeanChannel(px, 1), 20.0 * geometry, 1e-4 * 20.0 * geometry);
}

TEST(Lights, DeltaDistantLightGivesItsIrradianceTimesCosine) {
    SceneDesc d = FloorScene(0.5f);
    const float theta = 0.6f;  // from the zenith
    d.distant_lights.push_back({Vec3(std::sin(theta), -std::cos(theta), 0.f), 0.f, Color(3.f)});
    Scene scene(d);
    auto px = Render(scene, LookDownAtOrigin(1.f), {4, 0, 1, 1}, {0, 0, 4, 4});
    EXPECT_NEAR(MeanChannel(px, 0), 0.5 / kPi * 3.0 * std::cos(theta), 1e-5);
}

TEST(Lights, SunConeDeliversPiLSin2OnAFacingSurface) {
    // Radiance L in a cone of half angle a straight overhead: E = pi L sin^2(a).
    SceneDesc d = FloorScene(0.5f);
    const float half = 0.2f, L = 7.f;
    d.distant_lights.push_back({Vec3(0, -1, 0), half, Color(L)});
    Scene scene(d);
    auto px = Render(scene, LookDownAtOrigin(1.f, 16), {64, 0, 1, 1}, {0, 0, 16, 16});
    const double expected = 0.5 / kPi * kPi * L * std::sin(half) * std::sin(half);
    // Light sampling of a cone over a Lambertian floor: each sample's weight varies only
    // with cos(theta) in [cos(half), 1], so 16K samples pin the mean to well under 1 %.
    EXPECT_NEAR(MeanChannel(px, 0), expected, 0.01 * expected);
}

TEST(Lights, ConstantDomeSeenDirectlyAndOverAFloor) {
    SceneDesc d = FloorScene(0.5f);
    d.dome_radiance = Color(0.25f, 1.f, 2.f);
    Scene scene(d);
    // Looking up: the dome itself, exactly.
    Camera up{{0, 1, 0}, Vec3(1, 0, 0), Vec3(0, 0, 1), Vec3(0, 1, 0), 0.5f, 0.5f, 4, 4};
    auto sky = Render(scene, up, {4, 0, 8, 1}, {0, 0, 4, 4});
    EXPECT_EQ(sky[0], 0.25f);
    EXPECT_EQ(sky[2], 2.f);
    EXPECT_EQ(sky[3], 0.f);  // alpha counts geometry only
    // Looking down: an unoccluded floor under a uniform sky reflects a * L.
    auto floor = Render(scene, LookDownAtOrigin(1.f, 16), {64, 0, 8, 1}, {0, 0, 16, 16});
    EXPECT_NEAR(MeanChannel(floor, 1), 0.5 * 1.0, 0.01);
    EXPECT_NEAR(MeanChannel(floor, 2), 0.5 * 2.0, 0.02);
}

TEST(Scene, RejectsBadLights) {
    SceneDesc d = FloorScene(0.5f);
    d.distant_lights.push_back({Vec3(0, 0, 0), 0.1f, Color(1.f)});
    EXPECT_THROW(Scene{d}, std::invalid_argument);
    d = FloorScene(0.5f);
    d.point_lights.push_back({Vec3(NAN, 0, 0), Color(1.f)});
    EXPECT_THROW(Scene{d}, std::invalid_argument);
    d = FloorScene(0.5f);
    d.dome_radiance = Color(-1.f);
    EXPECT_THROW(Scene{d}, std::invalid_argument);
}

// Light tracing and path tracing estimate the same image; with every kind of light in the
// scene this checks each light's emission sampling (light tracer) against its direct
// sampling and MIS (path tracer).
//
// Statistics: 4 quadrants x 3 channels of mean radiance per run, K independent runs per
// integrator; light vs path and bdpt vs path are compared with Welch's t-test at a
// family-wise false-alarm rate of 1e-3 over the 24 comparisons (Bonferroni). Power: the
// smallest relative difference each comparison detects (limit x standard error / mean) is
// asserted below 2 % for every statistic (measured: 1.35 % at worst, 32 runs x 256 spp, ~16 s), and the negative control
// scales the light and bdpt results by 1.02 and requires every one of the 24 comparisons to
// flag it.
TEST(Integrators, PathLightAndBidirectionalAgreeForEveryLightKind) {
    // A floor of modest size: lights at infinity emit over the scene's bounding disk, and a
    // huge disk would make the light tracer correct but far too noisy to compare.
    SceneDesc d = FloorScene(0.6f, 4.f);
    uint32_t grey = AddMaterial(d, Color(0.4f, 0.5f, 0.3f), Color(0.f));
    AddQuad(d, {-1, 1.5f, -1}, {1, 1.5f, -1}, {1, 1.5f, 1}, {-1, 1.5f, 1}, grey);  // a shelf casting shadows
    d.point_lights.push_back({Vec3(2, 3, 1), Color(30.f, 20.f, 10.f)});
    d.sphere_lights.push_back({Vec3(-2, 2.5f, -1), 0.4f, Color(5.f, 8.f, 12.f)});
    d.distant_lights.push_back({Normalize(Vec3(0.3f, -1, 0.2f)), 0.0f, Color(0.8f, 0.7f, 0.6f)});
    d.distant_lights.push_back({Normalize(Vec3(-0.4f, -1, 0.1f)), 0.1f, Color(4.f)});
    d.dome_radiance = Color(0.05f, 0.08f, 0.12f);
    Scene scene(d);
    const uint32_t W = 24, H = 24;
    Camera cam{{0, 4, 6}, Vec3(1, 0, 0), Normalize(Vec3(0, 0.83f, -0.55f)), Normalize(Vec3(0, -0.55f, -0.83f)),
               0.6f, 0.6f, W, H};

    const int K = 32;
    const uint32_t spp = 256;
    // Per run: 4 quadrants x 3 channels of mean radiance.
    auto quadrants = [&](const std::vector<float>& img) {
        std::array<double, 12> q{};
        for (uint32_t y = 0; y < H; ++y)
            for (uint32_t x = 0; x < W; ++x)
                for (int c = 0; c < 3; ++c) q[((y >= H / 2) * 2 + (x >= W / 2)) * 3 + c] += img[4 * (y * W + x) + c];
        for (double& v : q) v /= double(W * H / 4);
        return q;
    };
    auto splatting_render = [&](RenderOptions opt) {
        std::vector<int64_t> splats(size_t(W) * H * 3, 0);
        std::vector<float> img(size_t(W) * H * 4);
        RenderStats stats = RenderTile(scene, cam, opt, {0, 0, W, H}, img.data(), nullptr, splats.data());
        EXPECT_EQ(stats.rejected_splats, 0u);
        EXPECT_EQ(stats.nonfinite_samples, 0u);
        EXPECT_EQ(stats.light_paths, uint64_t(W) * H * spp);
        const double scale = double(W * H) / (SplatScale(scene.splat_exponent()) * double(stats.light_paths));
        for (size_t i = 0; i < size_t(W) * H; ++i)
            for (int c = 0; c < 3; ++c) img[4 * i + c] += float(double(splats[3 * i + c]) * scale);
        return img;
    };
    std::vector<std::array<double, 12>> path_runs, light_runs, bdpt_runs;
    for (int k = 0; k < K; ++k) {
        RenderOptions opt{spp, uint32_t(100 + k), 16, 2};
        path_runs.push_back(quadrants(Render(scene, cam, opt, {0, 0, W, H})));
        opt.integrator = "light";
        light_runs.push_back(quadrants(splatting_render(opt)));
        opt.integrator = "bdpt";
        bdpt_runs.push_back(quadrants(splatting_render(opt)));
    }
    auto stats = [&](const std::vector<std::array<double, 12>>& runs, int s, double* mean, double* var) {
        *mean = *var = 0;
        for (int k = 0; k < K; ++k) *mean += runs[k][s] / K;
        for (int k = 0; k < K; ++k) *var += std::pow(runs[k][s] - *mean, 2) / (K - 1);
    };
    const int comparisons = 24;
    const double alpha = 1e-3 / comparisons;
    double worst_detectable = 0;
    for (int s = 0; s < 12; ++s) {
        double mp, ml, mb, vp, vl, vb;
        stats(path_runs, s, &mp, &vp);
        stats(light_runs, s, &ml, &vl);
        stats(bdpt_runs, s, &mb, &vb);
        const char* names[2] = {"light", "bdpt"};
        const double means[2] = {ml, mb}, vars[2] = {vl, vb};
        for (int i = 0; i < 2; ++i) {
            Welch w = WelchT(means[i], vars[i], K, mp, vp, K);
            double limit = StudentTCritical(alpha, w.df);
            EXPECT_LT(std::abs(w.t), limit) << "statistic " << s << ": path " << mp << " " << names[i] << " "
                                            << means[i] << " (t = " << w.t << ", df " << w.df << ")";
            double detectable = limit * w.se / mp;
            worst_detectable = std::max(worst_detectable, detectable);
            EXPECT_LT(detectable, 0.02) << "statistic " << s << " (" << names[i] << ") detects only "
                                        << 100 * detectable << " %";
            // Negative control: the same comparison with this integrator 2 % too bright fails.
            Welch biased = WelchT(1.02 * means[i], 1.02 * 1.02 * vars[i], K, mp, vp, K);
            EXPECT_GT(std::abs(biased.t), StudentTCritical(alpha, biased.df))
                << "statistic " << s << ": " << names[i] << " x 1.02 passes (t = " << biased.t << ")";
        }
    }
    std::printf("worst detectable relative difference: %.2f %%\n", 100 * worst_detectable);
}

namespace {

// A UsdPreviewSurface as exporters write a plain diffuse material: metallic 0, roughness 1,
// ior 1 (no interface, so no specular): it must render as Lambert of albedo rho.
MaterialParams PlainDiffusePreview(Color rho) {
    MaterialParams p;
    p.diffuse_color = rho;
    p.metallic = 0.f;
    p.roughness = 1.f;
    p.ior = 1.f;
    return p;
}

uint32_t AddPreview(SceneDesc& d, const MaterialParams& p, Color emission = Color(0.f), bool two_sided = false) {
    d.materials.push_back({p.diffuse_color, emission, two_sided, p});
    return uint32_t(d.materials.size() - 1);
}

double MeanOverPixels(const std::vector<float>& px, int c, double* stderr_mean) {
    double sum = 0, sum2 = 0, n = double(px.size() / 4);
    for (size_t i = 0; i < px.size() / 4; ++i) sum += px[4 * i + c], sum2 += double(px[4 * i + c]) * px[4 * i + c];
    double mean = sum / n;
    *stderr_mean = std::sqrt(std::max(0.0, sum2 / n - mean * mean) / n);
    return mean;
}

}  // namespace

// Every wall a smooth metal of reflectance c (UsdPreviewSurface metallic = 1, roughness 0:
// F0 = F90 = c at every angle) emitting Le: each path is a chain of perfect reflections, so
// L = Le (1 + c + c^2 + ...) = Le / (1 - c).
TEST(Materials, SmoothMetalFurnaceIsLeOverOneMinusReflectance) {
    MaterialParams metal;
    metal.diffuse_color = Color(0.8f, 0.5f, 0.2f);
    metal.metallic = 1.f;
    metal.roughness = 0.f;
    SceneDesc d;
    const Color Le(1.f, 2.f, 0.5f);
    AddInwardBox(d, {-1, -2, -1.5f}, {3, 1, 2}, AddPreview(d, metal, Le, true));
    Scene scene(d);
    for (const char* integrator : {"path", "bdpt", "whitted"}) {
        std::vector<float> px(16 * 16 * 4);
        std::vector<int64_t> splats(16 * 16 * 3, 0);
        RenderOptions opt{64, 4, 10000, 2};
        opt.integrator = integrator;
        RenderTile(scene, LookDownMinusZ({0.2f, -0.3f, 0.1f}, 16, 16, 1.f), opt, {0, 0, 16, 16}, px.data(), nullptr,
                   splats.data());
        for (int c = 0; c < 3; ++c) {
            double se, mean = MeanOverPixels(px, c, &se);  // no t = 1 strategies reach a pinhole via mirrors
            double expected = Le[c] / (1.0 - metal.diffuse_color[c]);
            EXPECT_NEAR(mean, expected, 5 * se + 1e-4 * expected) << "channel " << c << " integrator " << integrator;
        }
    }
}

// The furnace with UsdPreviewSurface walls: metallic 0, roughness 1, ior 1 (no interface,
// so no specular) and diffuse a must read Le / (1 - a) like Lambertian walls (it read -6 %
// at a = 0.5 and -42 % at a = 0.9 when the diffuse was dimmed by Schlick at both ends).
// Tolerance 0.5 % of the expected value with 4 se below it; detects 1 %: the negative
// control (the same check against an expectation 1 % off) must fail.
TEST(Materials, PreviewSurfaceFurnaceIsLeOverOneMinusAlbedo) {
    for (float a : {0.5f, 0.9f}) {
        const MaterialParams wall = PlainDiffusePreview(Color(a));
        SceneDesc d;
        const Color Le(0.5f, 1.f, 2.f);
        AddInwardBox(d, {-1, -2, -1.5f}, {3, 1, 2}, AddPreview(d, wall, Le, true));
        Scene scene(d);
        const uint32_t W = 24, H = 24;
        auto px = Render(scene, LookDownMinusZ({0.2f, -0.3f, 0.1f}, W, H, 1.2f), {1024, 11, 100000, 2}, {0, 0, W, H});
        for (int c = 0; c < 3; ++c) {
            double se, mean = MeanOverPixels(px, c, &se);
            double expected = Le[c] / (1.0 - a), tol = 0.005 * expected;
            std::printf("albedo %.1f channel %d: %.5f of Le/(1-a)\n", a, c, mean / expected);
            EXPECT_LT(4 * se, tol) << "too noisy to see 1 %";
            EXPECT_NEAR(mean, expected, tol) << "channel " << c << " albedo " << a;
            EXPECT_GT(std::abs(mean - 1.01 * expected), tol) << "negative control";
        }
    }
}

// A plain diffuse UsdPreviewSurface (ior 1, roughness 1) under a delta DistantLight at 60°
// reflects E cos(60°) ρ / pi exactly (it read -3.1 % = (1 - cos 60)^5 before). The result
// is noiseless (one light, one bounce), so the tolerance is 0.2 %; the negative control
// checks that a 1 % error would be flagged.
TEST(Materials, PreviewSurfaceUnderDistantLightIsLambert) {
    const MaterialParams p = PlainDiffusePreview(Color(0.5f));
    SceneDesc d;
    const float s = 1000.f;
    AddQuad(d, {-s, 0, -s}, {-s, 0, s}, {s, 0, s}, {s, 0, -s}, AddPreview(d, p));
    const float theta = float(kPi / 3.0);  // 60° from the normal
    d.distant_lights.push_back({Vec3(std::sin(theta), -std::cos(theta), 0.f), 0.f, Color(3.f)});
    Scene scene(d);
    auto px = Render(scene, LookDownAtOrigin(1.f), {4, 0, 1, 1}, {0, 0, 4, 4});
    const double expected = 0.5 / kPi * 3.0 * std::cos(double(theta)), tol = 0.002 * expected;
    const double mean = MeanChannel(px, 0);
    std::printf("60 degree distant light: %.5f of E cos rho / pi\n", mean / expected);
    EXPECT_NEAR(mean, expected, tol);
    EXPECT_GT(std::abs(mean - 1.01 * expected), tol) << "negative control";
}

// A smooth dielectric UsdPreviewSurface (black diffuse, ior 1.5) reflecting a large emitter:
// the pixel is Le times Schlick's Fresnel at the angle of incidence.
TEST(Materials, SmoothSpecularReflectsSchlickFresnel) {
    MaterialParams mirror;
    mirror.diffuse_color = Color(0.f);
    mirror.roughness = 0.f;
    mirror.ior = 1.5f;
    SceneDesc d;
    AddQuad(d, {-50, 0, -50}, {-50, 0, 50}, {50, 0, 50}, {50, 0, -50}, AddPreview(d, mirror));  // faces +y
    const Color Le(3.f, 3.f, 3.f);
    AddQuad(d, {-500, 20, -500}, {500, 20, -500}, {500, 20, 500}, {-500, 20, 500},
            AddMaterial(d, Color(0.f), Le));  // faces -y
    Scene scene(d);
    const float theta = 1.05f;  // ~60 degrees from the normal
    Vec3 fwd(std::sin(theta), -std::cos(theta), 0.f);
    Camera cam{{0, 1, 0}, Vec3(0, 0, -1), Normalize(Cross(Vec3(0, 0, -1), fwd)), fwd, 1e-4f, 1e-4f, 4, 4};
    auto px = Render(scene, cam, {16, 1, 8, 1}, {0, 0, 4, 4});
    const double f0 = 0.04, cos_t = std::cos(theta);
    const double schlick = f0 + (1 - f0) * std::pow(1 - cos_t, 5);
    EXPECT_NEAR(MeanChannel(px, 1), 3.0 * schlick, 1e-3 * 3.0 * schlick);
}

// Clear glass (opacity 0, ior 1.5, smooth) as a slab in front of an emitter, at normal
// incidence: with R = ((n - 1) / (n + 1))^2 and every internal reflection, T = (1 - R) / (1 + R).
// The radiance scaling by n^2 going in is undone coming out.
TEST(Materials, GlassSlabTransmitsOneMinusROverOnePlusR) {
    MaterialParams glass;
    glass.opacity = 0.f;
    glass.roughness = 0.f;
    glass.ior = 1.5f;
    SceneDesc d;
    uint32_t g = AddPreview(d, glass);
    AddQuad(d, {-50, -50, -1}, {50, -50, -1}, {50, 50, -1}, {-50, 50, -1}, g);          // front, normal +z
    AddQuad(d, {-50, -50, -1.2f}, {-50, 50, -1.2f}, {50, 50, -1.2f}, {50, -50, -1.2f}, g);  // back, normal -z
    const Color Le(2.f);
    AddQuad(d, {-500, -500, -5}, {500, -500, -5}, {500, 500, -5}, {-500, 500, -5}, AddMaterial(d, Color(0.f), Le));
    Scene scene(d);
    const double R = 0.04, expected = 2.0 * (1 - R) / (1 + R);
    for (const char* integrator : {"path", "whitted"}) {
        std::vector<float> px(16 * 16 * 4);
        RenderOptions opt{256, 2, 64, 2};
        opt.integrator = integrator;
        RenderTile(scene, LookDownMinusZ({0, 0, 0}, 16, 16, 1e-4f), opt, {0, 0, 16, 16}, px.data());
        double se, mean = MeanOverPixels(px, 0, &se);
        EXPECT_NEAR(mean, expected, 5 * se + 1e-4) << "integrator " << integrator;
        EXPECT_LT(se, 0.01 * expected);
    }
}

TEST(Integrators, LocalIsExactOnAOneBounceScene) {
    // A floor lit by a point light: only L D E paths exist; local shading gets them exactly.
    SceneDesc d = FloorScene(0.6f);
    d.point_lights.push_back({Vec3(3, 4, 0), Color(10.f)});
    Scene scene(d);
    RenderOptions opt{4, 0, 64, 1};
    opt.integrator = "local";
    auto px = Render(scene, LookDownAtOrigin(1.f), opt, {0, 0, 4, 4});
    EXPECT_NEAR(MeanChannel(px, 0), 10.0 * 0.6 / kPi * 0.8 / 25.0, 1e-6);
    // In a closed box it misses the indirect light that path tracing adds.
    Scene box(SmallCornell());
    Camera cam = LookDownMinusZ({0, 0, 1.5f}, 16, 16, 0.45f);
    auto local = Render(box, cam, opt, {0, 0, 16, 16});
    RenderOptions one_bounce{4, 0, 1, 1};
    auto path1 = Render(box, cam, one_bounce, {0, 0, 16, 16});
    EXPECT_EQ(0, std::memcmp(local.data(), path1.data(), local.size() * sizeof(float)));
    auto full = Render(box, cam, {4, 0, 64, 1}, {0, 0, 16, 16});
    EXPECT_GT(MeanChannel(full, 1), 1.2 * MeanChannel(local, 1));
}

// Whitted against closed forms on scenes whose only paths are L [D|S] S_M* E.
TEST(Integrators, WhittedSeesAPointLitFloorThroughAMirrorExactly) {
    // Camera -> smooth metal mirror (reflectance c) -> Lambertian floor lit by a point light:
    // the pixel is c * a/pi * I cos(theta) / d^2 at the floor point seen in the mirror.
    SceneDesc d = FloorScene(0.5f);
    MaterialParams metal;
    metal.diffuse_color = Color(0.7f);
    metal.metallic = 1.f;
    metal.roughness = 0.f;
    // A mirror at y = 2 facing down; the camera at y = 1 looks straight up into it.
    AddQuad(d, {-1, 2, -1}, {1, 2, -1}, {1, 2, 1}, {-1, 2, 1}, AddPreview(d, metal));
    d.point_lights.push_back({Vec3(3, 4, 0), Color(10.f)});  // lights the floor around the origin
    Scene scene(d);
    Camera up{{0, 1, 0}, Vec3(1, 0, 0), Vec3(0, 0, 1), Vec3(0, 1, 0), 1e-4f, 1e-4f, 4, 4};
    RenderOptions opt{4, 0, 64, 1};
    opt.integrator = "whitted";
    auto px = Render(scene, up, opt, {0, 0, 4, 4});
    // The floor point is the origin: d = 5, cos = 4/5. The mirror also shadows nothing there.
    EXPECT_NEAR(MeanChannel(px, 0), 0.7 * 0.5 / kPi * 10.0 * 0.8 / 25.0, 1e-6);
}

namespace {

// Fraction of a disk of radius R whose x coordinate is below a.
double DiskFractionBelow(double a, double R) {
    if (a <= -R) return 0.0;
    if (a >= R) return 1.0;
    return 0.5 + (a * std::sqrt(R * R - a * a) + R * R * std::asin(a / R)) / (kPi * R * R);
}

}  // namespace

// Depth of field against geometry: an emitting half-plane (x < 0) at depth z_obj in front
// of the focus plane z_f. The ray from lens point (lx, ly) through focus-plane point
// (fx, fy) crosses depth z_obj at x = lx (1 - k) + fx k, k = z_obj / z_f, so a pixel's value
// is Le times the fraction of the lens disk with lx < -fx k / (1 - k).
TEST(Camera, ThinLensBlurIsTheLensFractionSeeingTheEmitter) {
    SceneDesc d;
    const Color Le(1.f);
    const float z_obj = 2.f, z_f = 5.f, R = 0.2f;
    AddQuad(d, {-100, -100, -z_obj}, {0, -100, -z_obj}, {0, 100, -z_obj}, {-100, 100, -z_obj},
            AddMaterial(d, Color(0.f), Le));  // x < 0, facing +z
    Scene scene(d);
    const uint32_t W = 32, H = 1;
    Camera cam = LookDownMinusZ({0, 0, 0}, W, H, 0.05f);  // focus-plane x spans +-0.25
    cam.lens_radius = R;
    cam.focal_distance = z_f;
    auto px = Render(scene, cam, {1024, 3, 4, 1}, {0, 0, W, H});
    const double k = z_obj / z_f;
    for (uint32_t x = 0; x < W; ++x) {
        // Average the analytic fraction over the pixel's footprint on the focus plane.
        double expected = 0;
        for (int j = 0; j < 64; ++j) {
            double fx = ((x + (j + 0.5) / 64.0) / W * 2.0 - 1.0) * 0.05 * z_f;
            expected += DiskFractionBelow(-fx * k / (1 - k), R) / 64.0;
        }
        EXPECT_NEAR(px[4 * x], expected, 0.01) << "pixel " << x;
    }
    // The blur is real: the middle of the image is neither 0 nor 1.
    EXPECT_GT(px[4 * (W / 2)], 0.2f);
    EXPECT_LT(px[4 * (W / 2)], 0.8f);
}

TEST(Camera, LensPathLightAndBidirectionalAgree) {
    // The thin lens in light tracing and BDPT (lens sampling, focus-plane projection,
    // importance) against the camera rays of path tracing.
    Scene scene(SmallCornell());
    const uint32_t W = 16, H = 16;
    Camera cam = LookDownMinusZ({0, 0, 1.5f}, W, H, 0.45f);
    cam.lens_radius = 0.15f;
    cam.focal_distance = 2.0f;
    // Detects 2 % (asserted and shown by a negative control in the helper).
    ExpectPathLightBDPTAgree(scene, cam, RenderOptions{256, 7, 16, 2}, 1, 16, 0.05);
}

// Window geometry against closed forms: a unit emitting square x in [0, 1], y in
// [-0.5, 0.5] on a black backdrop. Orthographic, a 4 x 4 unit window over 16 x 16 pixels
// (4 pixels a unit) covers columns 8-11 and rows 6-9 at any depth; shifted by one unit
// right, columns 4-7. Perspective at depth 2 with tan(fov/2) = 0.5 shifted by 0.25: the
// window spans x in [-0.5, 1.5] there (8 pixels a unit), the square columns 4-11 and
// rows 4-11.
TEST(Camera, OrthographicAndShiftedWindowsPutASquareWhereTheGeometrySays) {
    auto square_at = [](float depth) {
        SceneDesc d;
        AddQuad(d, {0, -0.5f, -depth}, {1, -0.5f, -depth}, {1, 0.5f, -depth}, {0, 0.5f, -depth},
                AddMaterial(d, Color(0.f), Color(1.f)));
        AddQuad(d, {-50, -50, -2 * depth}, {50, -50, -2 * depth}, {50, 50, -2 * depth}, {-50, 50, -2 * depth},
                AddMaterial(d, Color(0.f), Color(0.f)));
        return d;
    };
    auto expect_columns_rows = [](const std::vector<float>& px, uint32_t x0, uint32_t x1, uint32_t y0,
                                  uint32_t y1, const char* what) {
        for (uint32_t y = 0; y < 16; ++y)
            for (uint32_t x = 0; x < 16; ++x) {
                const float expected = (x >= x0 && x < x1 && y >= y0 && y < y1) ? 1.f : 0.f;
                EXPECT_NEAR(px[4 * (16 * y + x)], expected, 1e-3) << what << " pixel " << x << ", " << y;
            }
    };
    for (float depth : {3.f, 30.f}) {
        Scene scene(square_at(depth));
        Camera ortho = LookDownMinusZ({0, 0, 0}, 16, 16, 2.f);
        ortho.projection = Projection::kOrthographic;
        expect_columns_rows(Render(scene, ortho, {16, 0, 4, 1}, {0, 0, 16, 16}), 8, 12, 6, 10, "orthographic");
        ortho.shift_x = 1.f;
        expect_columns_rows(Render(scene, ortho, {16, 0, 4, 1}, {0, 0, 16, 16}), 4, 8, 6, 10, "shifted orthographic");
    }
    Scene scene(square_at(2.f));
    Camera persp = LookDownMinusZ({0, 0, 0}, 16, 16, 0.5f);
    persp.shift_x = 0.25f;
    expect_columns_rows(Render(scene, persp, {16, 0, 4, 1}, {0, 0, 16, 16}), 4, 12, 4, 12, "shifted perspective");
}

TEST(Camera, OrthographicAndShiftedPathLightBidirectionalAndVcmAgree) {
    // The parallel beam's importance (1 / A, no 1/d^2) and bdpt's per-film-area densities
    // against the camera rays of path tracing, looking down into the box at an angle so
    // the floor and the block are seen; the window shifted off-centre.
    Scene scene(SmallCornell());
    const uint32_t W = 16, H = 16;
    Camera cam{{0, 0.4f, 0}, Vec3(1, 0, 0), Normalize(Vec3(0, 1, -0.4f)), Normalize(Vec3(0, -0.4f, -1)),
               0.7f, 0.6f, W, H};
    cam.projection = Projection::kOrthographic;
    cam.shift_x = 0.15f;
    cam.shift_y = -0.1f;
    // Detects 2 % (asserted and shown by a negative control in the helper).
    ExpectPathLightBDPTAgree(scene, cam, RenderOptions{256, 7, 16, 2}, 1, 16, 0.05, {"light", "bdpt", "vcm"});
    Camera shifted = LookDownMinusZ({0, 0, 1.5f}, W, H, 0.3f);
    shifted.shift_x = 0.12f;
    shifted.shift_y = 0.08f;
    ExpectPathLightBDPTAgree(scene, shifted, RenderOptions{256, 7, 16, 2}, 1, 16, 0.05, {"light", "bdpt"});
}

TEST(Camera, ClippingRangeHidesGeometryOutsideIt) {
    SceneDesc d;
    AddQuad(d, {-10, -10, -5}, {10, -10, -5}, {10, 10, -5}, {-10, 10, -5}, AddMaterial(d, Color(0.f), Color(2.f)));
    AddQuad(d, {-10, -10, -1}, {10, -10, -1}, {10, 10, -1}, {-10, 10, -1}, AddMaterial(d, Color(0.f), Color(0.f)));
    Scene scene(d);
    Camera cam = LookDownMinusZ({0, 0, 0}, 4, 4, 0.1f);
    EXPECT_EQ(Render(scene, cam, {2, 0, 4, 1}, {0, 0, 4, 4})[0], 0.f);  // the black blocker
    cam.near = 2.f;                                                     // clipped away
    EXPECT_EQ(Render(scene, cam, {2, 0, 4, 1}, {0, 0, 4, 4})[0], 2.f);
    cam.far = 4.f;  // and now the emitter too
    auto none = Render(scene, cam, {2, 0, 4, 1}, {0, 0, 4, 4});
    EXPECT_EQ(none[0], 0.f);
    EXPECT_EQ(none[3], 0.f);
}

namespace {

// A lat-long texture with a gradient and one bright texel; lat-long (u, v) of a direction
// in the dome's frame (identity rotation here).
SceneDesc TexturedDome(uint32_t w, uint32_t h, uint32_t hot_x, uint32_t hot_y) {
    SceneDesc d;
    d.dome_radiance = Color(1.f);
    d.dome_width = w;
    d.dome_height = h;
    d.dome_rgb.resize(size_t(w) * h * 3);
    for (uint32_t y = 0; y < h; ++y)
        for (uint32_t x = 0; x < w; ++x)
            for (int c = 0; c < 3; ++c)
                d.dome_rgb[3 * (size_t(y) * w + x) + c] = 0.05f + 0.1f * float(x) / w + (c == 2 ? 0.05f : 0.f);
    for (int c = 0; c < 3; ++c) d.dome_rgb[3 * (size_t(hot_y) * w + hot_x) + c] = 40.f;
    return d;
}

Vec2 LatLong(Vec3 w) {
    float lat = std::asin(std::clamp(w.y, -1.f, 1.f)), lon = std::atan2(w.x, w.z);
    return {0.5f - lon * kInv2Pi, 0.5f - lat * kInvPi};
}

}  // namespace

TEST(Dome, SampledTexelsFollowTheDistributionAndPdfsAgree) {
    const uint32_t W = 16, H = 8;
    SceneDesc d = TexturedDome(W, H, 11, 3);
    Scene scene(d);
    ASSERT_EQ(scene.num_emitters(), 1u);
    std::vector<double> weight(W * H), observed(W * H, 0.0), expected(W * H);
    double total = 0;
    for (uint32_t y = 0; y < H; ++y)
        for (uint32_t x = 0; x < W; ++x) {
            const float* t = &d.dome_rgb[3 * (y * W + x)];
            weight[y * W + x] = Luminance(Color(t[0], t[1], t[2])) * std::sin(kPi * (y + 0.5) / H);
            total += weight[y * W + x];
        }
    const int n = 400000;
    for (int i = 0; i < n; ++i) {
        PixelSampler s(4, uint64_t(i), 0);
        LightSample ls;
        ASSERT_TRUE(scene.SampleEmitter(0, Vec3(0.f), s.Get2D(), &ls));
        Vec2 uv = LatLong(ls.wi);
        uint32_t x = std::min(W - 1, uint32_t(uv.x * W)), y = std::min(H - 1, uint32_t(uv.y * H));
        observed[y * W + x] += 1;
        if (i % 97 == 0) {  // the pdf the sample reports is the pdf of its direction
            float pdf = -1.f;
            scene.ForEachEnvironmentLight(Vec3(0.f), ls.wi, [&](uint32_t, Color, float p) { pdf = p; });
            EXPECT_NEAR(pdf, ls.pdf, 2e-3f * ls.pdf);
        }
    }
    for (uint32_t i = 0; i < W * H; ++i) expected[i] = n * weight[i] / total;
    auto r = tessera::testing::ChiSquareTest(observed, expected);
    EXPECT_TRUE(r.pass) << "chi2 " << r.statistic << " dof " << r.dof;
}

TEST(Dome, OrientationFollowsTheOpenEXRLatLongConvention) {
    // Texel column x covers longitude pi (1 - 2 (x + [0,1]) / W): the hot texel at
    // x = W/4 - 1, y = H/2 sits just before longitude pi/2 at the equator, i.e. toward +x.
    const uint32_t W = 16, H = 8;
    SceneDesc d = TexturedDome(W, H, W / 4 - 1, H / 2 - 1);
    Scene scene(d);
    auto look = [&](Vec3 fwd) {
        Vec3 up = std::abs(fwd.y) > 0.9f ? Vec3(0, 0, 1) : Vec3(0, 1, 0);
        Vec3 right = Normalize(Cross(fwd, up));
        Camera cam{{0, 0, 0}, right, Cross(right, fwd), fwd, 0.01f, 0.01f, 2, 2};
        // Aim just inside the hot texel: longitude pi/2 + a bit, latitude + a bit.
        return Render(scene, cam, {1, 0, 1, 1}, {0, 0, 2, 2});
    };
    const float dl = 0.5f * kPi / 8.f;  // half a texel in latitude / longitude
    Vec3 toward(std::cos(dl) * std::sin(kPi / 2 + dl), std::sin(dl), std::cos(dl) * std::cos(kPi / 2 + dl));
    EXPECT_EQ(look(Normalize(toward))[0], 40.f);
    EXPECT_LT(look(Vec3(-1, 0, 0))[0], 1.f);
    EXPECT_LT(look(Vec3(0, 0, 1))[0], 1.f);
}

TEST(Dome, TexturedDomeIntegratorsAgree) {
    SceneDesc d = TexturedDome(32, 16, 20, 4);
    uint32_t m = AddMaterial(d, Color(0.6f), Color(0.f));
    AddQuad(d, {-4, 0, -4}, {-4, 0, 4}, {4, 0, 4}, {4, 0, -4}, m);
    AddQuad(d, {-1, 1.5f, -1}, {1, 1.5f, -1}, {1, 1.5f, 1}, {-1, 1.5f, 1}, m);
    Scene scene(d);
    const uint32_t W = 16, H = 16;
    Camera cam{{0, 4, 6}, Vec3(1, 0, 0), Normalize(Vec3(0, 0.83f, -0.55f)), Normalize(Vec3(0, -0.55f, -0.83f)),
               0.6f, 0.6f, W, H};
    // Detects 2 % (asserted and shown by a negative control in the helper).
    ExpectPathLightBDPTAgree(scene, cam, RenderOptions{64, 11, 16, 2}, 0, 16, 0.05);
}

namespace {

// A UV sphere of radius r at c, with smooth corner normals when `smooth`.
void AddSphereMesh(SceneDesc& d, Vec3 c, float r, uint32_t material, bool smooth, int n_theta = 8, int n_phi = 12) {
    auto point = [&](int i, int j) {
        float th = kPi * float(i) / n_theta, ph = 2.f * kPi * float(j) / n_phi;
        return Vec3(std::sin(th) * std::cos(ph), std::cos(th), std::sin(th) * std::sin(ph));
    };
    for (int i = 0; i < n_theta; ++i)
        for (int j = 0; j < n_phi; ++j) {
            Vec3 a = point(i, j), b = point(i + 1, j), cc = point(i + 1, j + 1), e = point(i, j + 1);
            for (auto tri : {std::array<Vec3, 3>{a, e, cc}, std::array<Vec3, 3>{a, cc, b}}) {
                uint32_t base = uint32_t(d.positions.size() / 3);
                for (Vec3 q : tri) {
                    Vec3 p = c + q * r;
                    d.positions.insert(d.positions.end(), {p.x, p.y, p.z});
                }
                d.indices.insert(d.indices.end(), {base, base + 1, base + 2});
                d.triangle_material.push_back(material);
                if (smooth)
                    for (Vec3 q : tri) d.shading_normals.insert(d.shading_normals.end(), {q.x, q.y, q.z});
            }
        }
}

}  // namespace

TEST(ShadingNormals, LambertianShadingFollowsTheShadingNormal) {
    // One quad facing +y whose corner normals all lean 30 degrees toward +x, lit by a delta
    // distant light from straight above: radiance a/pi E cos(30 deg), not a/pi E.
    SceneDesc d;
    uint32_t m = AddMaterial(d, Color(0.5f), Color(0.f));
    AddQuad(d, {-1, 0, -1}, {-1, 0, 1}, {1, 0, 1}, {1, 0, -1}, m);  // small, so light paths find the view
    const Vec3 n(std::sin(0.5236f), std::cos(0.5236f), 0.f);
    for (int k = 0; k < 6; ++k) d.shading_normals.insert(d.shading_normals.end(), {n.x, n.y, n.z});
    d.distant_lights.push_back({Vec3(0, -1, 0), 0.f, Color(2.f)});
    Scene scene(d);
    const double expected = 0.5 / kPi * 2.0 * std::cos(0.5236);
    auto px = Render(scene, LookDownAtOrigin(1.f), {4, 0, 1, 1}, {0, 0, 4, 4});
    EXPECT_NEAR(MeanChannel(px, 0), expected, 1e-5);
    // Seen obliquely, light tracing must give the same radiance: its light paths carry
    // importance, which needs the adjoint correction for shading normals (without it this
    // view would be off by |wc.ns| / |wc.ng| ~ 40 %).
    const uint32_t W = 8, H = 8;
    Vec3 fwd = Normalize(Vec3(-1.f, -0.6f, 0.f));
    Camera oblique{{1.5f, 0.9f, 0}, Vec3(0, 0, -1), Normalize(Cross(Vec3(0, 0, -1), fwd)), fwd, 0.15f, 0.15f, W, H};
    for (const char* integrator : {"path", "light", "bdpt"}) {
        RenderOptions opt{2048, 2, 1, 2};
        opt.integrator = integrator;
        auto img = RenderResolved(scene, oblique, opt);
        double sum = 0;
        for (size_t i = 0; i < size_t(W) * H; ++i) sum += img[4 * i + 0];
        EXPECT_NEAR(sum / (W * H), expected, 0.03 * expected) << "integrator " << integrator;
    }
}

TEST(ShadingNormals, SmoothSpheresKeepPathLightAndBidirectionalInAgreement) {
    // The importance correction for shading normals (light tracing, BDPT light subpaths)
    // against path tracing, which needs none.
    SceneDesc d = FloorScene(0.6f, 4.f);
    for (int k = 0; k < 6; ++k) d.shading_normals.insert(d.shading_normals.end(), {0.f, 1.f, 0.f});  // the floor's
    // Very coarse, so shading and geometric normals differ by up to ~45 degrees.
    AddSphereMesh(d, Vec3(0, 1, 0), 0.9f, AddMaterial(d, Color(0.8f, 0.6f, 0.4f), Color(0.f)), true, 3, 4);
    d.point_lights.push_back({Vec3(2, 3, 1), Color(30.f)});
    d.sphere_lights.push_back({Vec3(-2, 2.5f, -1), 0.4f, Color(8.f)});
    Scene scene(d);
    const uint32_t W = 16, H = 16;
    Camera cam{{0, 3, 5}, Vec3(1, 0, 0), Normalize(Vec3(0, 0.93f, -0.37f)), Normalize(Vec3(0, -0.37f, -0.93f)),
               0.6f, 0.6f, W, H};
    // Detects 2 % (asserted and shown by a negative control in the helper).
    ExpectPathLightBDPTAgree(scene, cam, RenderOptions{128, 5, 16, 2}, 0, 16, 0.05);
}

// The hand-written ulp steps against libm's nextafter, bit for bit, over the cases that
// differ in kind (zeros, denormals, the largest finite, infinities, NaN) and random floats.
TEST(Math, NextFloatUpAndDownAreNextafterBitForBit) {
    const float inf = std::numeric_limits<float>::infinity();
    std::vector<float> values = {0.f, -0.f, std::numeric_limits<float>::denorm_min(),
                                 -std::numeric_limits<float>::denorm_min(), std::numeric_limits<float>::min(),
                                 std::numeric_limits<float>::max(), -std::numeric_limits<float>::max(), inf, -inf,
                                 1.f, -1.f, 1e-30f, -3e7f};
    uint64_t state = 7;
    for (int i = 0; i < 100000; ++i) {
        state = state * 6364136223846793005ull + 1442695040888963407ull;
        values.push_back(std::bit_cast<float>(uint32_t(state >> 32)));
    }
    for (float v : values) {
        const float up = NextFloatUp(v), down = NextFloatDown(v);
        if (std::isnan(v)) {
            ASSERT_TRUE(std::isnan(up) && std::isnan(down));
            continue;
        }
        ASSERT_EQ(std::bit_cast<uint32_t>(up), std::bit_cast<uint32_t>(std::nextafter(v, inf))) << v;
        ASSERT_EQ(std::bit_cast<uint32_t>(down), std::bit_cast<uint32_t>(std::nextafter(v, -inf))) << v;
    }
    // Control: one ulp is told apart.
    EXPECT_NE(NextFloatUp(1.f), 1.f);
}
