// The path tracer in grid (heterogeneous) media against closed forms and against the
// homogeneous medium (docs/media.md).
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <memory>
#include <string>

#include "scene_helpers.h"

using namespace tessera_test;

namespace {

// Axis-aligned box [lo, hi] wound outward, as a pure interface with medium `inside` in it.
void AddMediumBox(SceneDesc& d, Vec3 lo, Vec3 hi, int32_t inside) {
    const uint32_t m = AddMaterial(d, Color(0.f), Color(0.f));
    d.materials[m].interface_only = true;
    d.materials[m].media.inside = inside;
    Vec3 p[8];
    for (int i = 0; i < 8; ++i) p[i] = Vec3(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z);
    AddQuad(d, p[0], p[2], p[3], p[1], m);
    AddQuad(d, p[4], p[5], p[7], p[6], m);
    AddQuad(d, p[0], p[1], p[5], p[4], m);
    AddQuad(d, p[2], p[6], p[7], p[3], m);
    AddQuad(d, p[0], p[4], p[6], p[2], m);
    AddQuad(d, p[1], p[3], p[7], p[5], m);
}

// A grid of n voxels a side filling [lo, hi], voxel (i, j, k) = density(i, j, k).
std::shared_ptr<DensityGrid> GridOver(Vec3 lo, Vec3 hi, int nx, int ny, int nz,
                                      const std::function<float(int, int, int)>& density) {
    auto g = std::make_shared<DensityGrid>();
    g->nx = nx, g->ny = ny, g->nz = nz;
    g->density.resize(size_t(nx) * ny * nz);
    for (int k = 0; k < nz; ++k)
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) g->density[(size_t(k) * ny + j) * nx + i] = density(i, j, k);
    const Vec3 s(nx / (hi.x - lo.x), ny / (hi.y - lo.y), nz / (hi.z - lo.z));
    const float m[12] = {s.x, 0, 0, -lo.x * s.x, 0, s.y, 0, -lo.y * s.y, 0, 0, s.z, -lo.z * s.z};
    std::copy(m, m + 12, g->world_to_index);
    return g;
}

float Ch(Color c, int k) { return k == 0 ? c.x : (k == 1 ? c.y : c.z); }

// An emitter Le (z = -3) behind a slab z in [-2, -1] of an absorbing grid medium, seen
// head-on through a narrow view (every ray crosses the slab along z).
std::vector<float> RenderGridSlab(Color sigma_a, Color Le, const std::function<float(int, int, int)>& density,
                                  uint32_t spp, uint32_t seed) {
    SceneDesc d;
    const Vec3 lo(-4, -4, -2), hi(4, 4, -1);
    d.grid_media.push_back({sigma_a, Color(0.f), 0.f, GridOver(lo, hi, 8, 8, 20, density)});
    const float s = 100.f;
    AddQuad(d, {-s, -s, -3}, {s, -s, -3}, {s, s, -3}, {-s, s, -3}, AddMaterial(d, Color(0.f), Le));
    AddMediumBox(d, lo, hi, 0);
    Scene scene(d);
    EXPECT_TRUE(scene.has_media());
    RenderOptions opt;
    opt.spp = spp;
    opt.seed = seed;
    return Render(scene, LookDownMinusZ({0, 0, 0}, 4, 4, 1e-4f), opt, {0, 0, 4, 4});
}

}  // namespace

// A constant grid of density 1 and sigma_a = tau (1, 1/2, 2) per unit density: each pixel
// reads Le e^-tau within 1 % (residual ratio tracking is exact in constant blocks), tau
// from 0.01 to 10. 2 % detected: the slab of tau + ln 1.02 fails.
TEST(PathGridMedia, ConstantAbsorbingGridSlabTransmitsBeerLambert) {
    const Color Le(1.f, 2.f, 0.5f);
    auto matches = [&](Color sigma, Color want) {
        const std::vector<float> img = RenderGridSlab(sigma, Le, [](int, int, int) { return 1.f; }, 4, 1);
        for (size_t i = 0; i < img.size() / 4; ++i)
            for (int k = 0; k < 3; ++k)
                if (!(std::abs(img[4 * i + k] / Ch(want, k) - 1.f) < 0.01f)) return false;
        return true;
    };
    for (float tau : {0.01f, 0.1f, 1.f, 3.f, 10.f}) {
        const Color sigma = Color(1.f, 0.5f, 2.f) * tau;
        const Color want = Le * Color(std::exp(-sigma.x), std::exp(-sigma.y), std::exp(-sigma.z));
        EXPECT_TRUE(matches(sigma, want)) << "tau " << tau;
        EXPECT_FALSE(matches(sigma + Color(std::log(1.02f)), want)) << "negative control, tau " << tau;
    }
}

// A heterogeneous absorbing slab whose density varies along the view (a ramp in z, 20
// voxels, thickness 1, normalised to optical depth tau per column) and across it
// (columns differ by a factor that integrates away: each column's ramp has the same
// integral), so ratio tracking is stochastic but every pixel's expectation is Le e^-tau.
// Image means of 8 seeds: within 1.2 % with a standard error under 0.3 %; 2 % detected
// (negative control: the closed form 2 % off lies outside the band).
TEST(PathGridMedia, RampAbsorbingGridSlabTransmitsBeerLambert) {
    const Color Le(1.f, 2.f, 0.5f);
    for (float tau : {0.5f, 1.f}) {
        // Voxel k of 20 holds (k + 0.5) / 10: its trilinear integral over the unit thickness
        // is exactly 1 (linear between centres, constant in the two half-voxel margins).
        auto ramp = [](int i, int j, int k) { return ((i + j) % 2 ? float(k + 0.5f) : float(19.5f - k)) / 10.f; };
        const Color sigma = Color(1.f, 0.5f, 2.f) * tau;
        std::vector<std::array<double, 3>> runs;
        for (uint32_t seed = 1; seed <= 8; ++seed) {
            const std::vector<float> img = RenderGridSlab(sigma, Le, ramp, 2048, seed);
            runs.push_back({MeanChannel(img, 0), MeanChannel(img, 1), MeanChannel(img, 2)});
        }
        const ChannelEstimate e = MeanAndStandardError(runs);
        for (int k = 0; k < 3; ++k) {
            const double want = Ch(Le, k) * std::exp(-double(Ch(sigma, k)));
            EXPECT_LT(e.stderr_mean[k], 0.003 * want) << "tau " << tau << " channel " << k;
            EXPECT_NEAR(e.mean[k], want, 0.012 * want) << "tau " << tau << " channel " << k;
            EXPECT_GT(std::abs(e.mean[k] - 1.02 * want), 0.012 * want) << "negative control";
        }
    }
}

// A grid of constant density D equals the homogeneous medium of coefficients D sigma, in
// a scene that scatters (albedo 0.8 grey, chromatic sigma, g = 0.3) a small emitter's light
// seen through a cube of the medium, per image half and channel (Welch's t, 16 seeds
// each). Power: the standard error of each difference is under 0.5 % of the mean, so a
// 2 % difference is t > 4; the negative control, the grid at density x 1.05 (each
// half's image changes by 2 % or more, checked), must be told apart by the same test.
TEST(PathGridMedia, ConstantGridEqualsHomogeneousMedium) {
    const Vec3 lo(-1, -1, -2.5f), hi(1, 1, -0.5f);
    const Color sigma_s = Color(0.8f, 0.4f, 1.2f), sigma_a = sigma_s * 0.25f;
    const float g = 0.3f;
    auto scene_with = [&](bool grid, float density) {
        SceneDesc d;
        if (grid)
            d.grid_media.push_back({sigma_a, sigma_s, g, GridOver(lo, hi, 16, 16, 16, [=](int, int, int) { return density; })});
        else
            d.media.push_back({sigma_a * density, sigma_s * density, g});
        AddQuad(d, {-2, -2, -3}, {2, -2, -3}, {2, 2, -3}, {-2, 2, -3}, AddMaterial(d, Color(0.f), Color(1.f)));
        AddMediumBox(d, lo, hi, 0);
        return Scene(d);
    };
    // Per seed, the mean of each half (left, right) of an 8 x 8 image, per channel.
    using Quadrants = std::array<std::array<double, 3>, 2>;
    auto render = [&](const Scene& scene) {
        std::vector<Quadrants> runs;
        RenderOptions opt;
        opt.spp = 384;
        for (uint32_t seed = 1; seed <= 16; ++seed) {
            opt.seed = seed;
            const std::vector<float> img = Render(scene, LookDownMinusZ({0, 0, 0}, 8, 8, 0.3f), opt, {0, 0, 8, 8});
            Quadrants q{};
            for (int y = 0; y < 8; ++y)
                for (int x = 0; x < 8; ++x)
                    for (int c = 0; c < 3; ++c) q[x / 4][c] += img[4 * (y * 8 + x) + c] / 32.0;
            runs.push_back(q);
        }
        return runs;
    };
    auto stats = [](const std::vector<Quadrants>& runs, int q, int c, double* mean, double* var) {
        double s = 0, s2 = 0;
        for (const Quadrants& r : runs) s += r[q][c];
        *mean = s / runs.size();
        for (const Quadrants& r : runs) s2 += (r[q][c] - *mean) * (r[q][c] - *mean);
        *var = s2 / (runs.size() - 1);
    };
    const auto homogeneous = render(scene_with(false, 1.f));
    const auto grid = render(scene_with(true, 1.f));
    const auto denser = render(scene_with(true, 1.05f));
    const double crit = StudentTCritical(1e-3 / 6, 15);  // 6 comparisons, family-wise 1e-3
    for (int q = 0; q < 2; ++q)
        for (int c = 0; c < 3; ++c) {
            double mh, vh, mg, vg, md, vd;
            stats(homogeneous, q, c, &mh, &vh);
            stats(grid, q, c, &mg, &vg);
            stats(denser, q, c, &md, &vd);
            const Welch same = WelchT(mg, vg, 16, mh, vh, 16), control = WelchT(md, vd, 16, mh, vh, 16);
            EXPECT_LT(same.se, 0.005 * mh) << "half " << q << " channel " << c;
            EXPECT_LT(std::abs(same.t), crit) << "half " << q << " channel " << c << ": " << mg << " vs " << mh;
            EXPECT_GT(std::abs(md / mh - 1), 0.02) << "the control must perturb by 2 %, half " << q;
            EXPECT_GT(std::abs(control.t), crit) << "negative control, half " << q << " channel " << c;
        }
}

TEST(PathGridMedia, BadGridMediaAreRefusedByName) {
    auto message = [](auto edit) {
        SceneDesc d = FloorScene(0.5f);
        d.grid_media.push_back(
            {Color(0.1f), Color(0.2f), 0.f, GridOver({-1, 1, -1}, {1, 2, 1}, 2, 2, 2, [](int, int, int) { return 1.f; })});
        AddMediumBox(d, {-1, 1, -1}, {1, 2, 1}, 0);
        edit(d);
        try {
            Scene s(d);
        } catch (const std::invalid_argument& e) {
            return std::string(e.what());
        }
        return std::string("no error");
    };
    EXPECT_EQ(message([](SceneDesc&) {}), "no error");
    EXPECT_NE(message([](SceneDesc& d) { d.grid_media[0].grid->density[1] = -1.f; }).find("grid medium 0"),
              std::string::npos);
    EXPECT_NE(message([](SceneDesc& d) { d.grid_media[0].grid.reset(); }).find("grid medium 0"), std::string::npos);
    EXPECT_NE(message([](SceneDesc& d) { d.materials.back().media.inside = 1; }).find("refers to medium 1 of 1"),
              std::string::npos);
}
