// PathIntegrator's Russian roulette setting (rr_depth): wherever roulette starts, the
// estimate stays unbiased, and a later start traces longer paths.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <vector>

#include "integrator.h"
#include "path.h"
#include "render.h"
#include "scene_helpers.h"

using namespace tessera;
using namespace tessera_test;

namespace {

struct FurnaceEstimate : ChannelEstimate {
    double closest_rays_per_sample = 0;
};

// K independent seeds of a whole image; the image means' mean and standard error.
FurnaceEstimate SeedMeans(const Scene& scene, const Camera& cam, RenderOptions opt, int seeds) {
    std::vector<std::array<double, 3>> per(seeds);
    uint64_t rays = 0, samples = 0;
    for (int k = 0; k < seeds; ++k) {
        opt.seed = 100 + uint32_t(k);
        RenderStats st;
        const std::vector<float> img = RenderResolved(scene, cam, opt, &st);
        rays += st.closest_rays;
        samples += st.samples;
        for (int c = 0; c < 3; ++c) per[k][c] = MeanChannel(img, c);
    }
    FurnaceEstimate e;
    static_cast<ChannelEstimate&>(e) = MeanAndStandardError(per);
    e.closest_rays_per_sample = double(rays) / double(samples);
    return e;
}

bool Agrees(const FurnaceEstimate& e, int c, double expected) {
    return std::abs(e.mean[c] - expected) <= 4.0 * e.stderr_mean[c] + 1e-4 * expected;
}

}  // namespace

// A closed Lambertian box whose walls (albedo a) all emit Le: the radiance is Le / (1 - a)
// everywhere, the sum over paths of every length (a^k Le from the k-th bounce), so ending
// paths early by roulette is unbiased only if every survivor is reweighted right. Checked
// for roulette from the first hit, from the default vertex and never (rr_depth beyond
// max_depth, where the bias of truncation at 100 bounces, a^100, is nil); each estimate's
// standard error is below 0.4 % of the closed form, and the same check fails a 2 % error.
TEST(Path, RouletteFromAnyVertexKeepsTheFurnaceAtLeOverOneMinusAlbedo) {
    const float a = 0.6f;
    const Color Le(0.5f, 1.f, 2.f);
    SceneDesc d;
    AddInwardBox(d, {-1, -2, -1.5f}, {3, 1, 2}, AddMaterial(d, Color(a), Le, true));
    const Scene scene(d);
    const Camera cam = LookDownMinusZ({0.2f, -0.3f, 0.1f}, 16, 16, 1.2f);
    double previous_rays = 0;
    for (int rr : {0, PathIntegrator::kDefaultRouletteDepth, 1000}) {
        RenderOptions opt;
        opt.spp = 16;
        opt.threads = 2;
        opt.max_depth = 100;
        opt.integrator = "path";
        opt.integrator_params = {{"rr_depth", float(rr)}};
        const FurnaceEstimate e = SeedMeans(scene, cam, opt, 16);
        for (int c = 0; c < 3; ++c) {
            const double expected = Le[c] / (1.0 - a);
            EXPECT_TRUE(Agrees(e, c, expected))
                << "rr_depth " << rr << " channel " << c << ": " << e.mean[c] << " +- " << e.stderr_mean[c]
                << " vs " << expected;
            EXPECT_GT(e.stderr_mean[c], 0.0);
            EXPECT_LT(e.stderr_mean[c], 0.004 * expected) << "rr_depth " << rr;
            EXPECT_FALSE(Agrees(e, c, 1.02 * expected)) << "rr_depth " << rr << ": a 2 % error would pass";
        }
        // A later start keeps paths alive longer: without roulette every path runs to
        // max_depth (100 bounces, 101 closest rays, in a closed box).
        EXPECT_GT(e.closest_rays_per_sample, previous_rays) << "rr_depth " << rr;
        previous_rays = e.closest_rays_per_sample;
        std::printf("path rr_depth %d: %.5f +- %.5f (closed form %.5f), %.2f closest rays per sample\n", rr,
                    e.mean[0], e.stderr_mean[0], Le[0] / (1.0 - a), e.closest_rays_per_sample);
    }
    EXPECT_GT(previous_rays, 100.9) << "without roulette, (almost) every path should run to max_depth";
}

TEST(Path, RouletteDepthMustBeAWholeNumberFromZero) {
    const Scene scene(FloorScene(0.5f));
    for (float bad : {-1.f, 1.5f, NAN, INFINITY}) {
        IntegratorSettings s;
        s.params = {{"rr_depth", bad}};
        EXPECT_THROW(Integrator::Create("path", s, scene), std::invalid_argument) << bad;
    }
    IntegratorSettings ok;
    ok.params = {{"rr_depth", 0.f}};
    EXPECT_NO_THROW(Integrator::Create("path", ok, scene));
}
