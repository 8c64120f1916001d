// The light tracer in homogeneous media (docs/media.md): the absorbing slab's closed form,
// and agreement with the path tracer where light scatters in a medium.
#include <gtest/gtest.h>

#include <cmath>
#include <string>

#include "media_scenes.h"

using namespace tessera_test;

namespace {

// As PathMedia's slab: an emitter Le facing the camera (z = -3) behind an absorbing slab
// z in [-2, -1] of thickness 1: every pixel reads Le e^(-sigma_a). The light tracer sees
// the emitter through its camera rays; its light paths leave the scene unscattered.
std::vector<float> RenderSlabWithLight(Color sigma_a, Color Le) {
    Scene scene(AbsorbingSlabBeforeEmitter(sigma_a, Le));
    RenderOptions opt;
    opt.spp = 4;
    opt.integrator = "light";
    return RenderResolved(scene, LookDownMinusZ({0, 0, 0}, 4, 4, 1e-4f), opt);
}

}  // namespace

// 2 % detected: each pixel within 1 %, and a slab of tau + ln 1.02 fails. Chromatic:
// sigma_a = tau (1, 1/2, 2), tau from 0.01 to 10.
TEST(LightMedia, AbsorbingSlabTransmitsBeerLambert) {
    EXPECT_TRUE(FindIntegrator("light")->handles_media);
    const Color Le(1.f, 2.f, 0.5f);
    for (float tau : {0.01f, 0.1f, 1.f, 3.f, 10.f}) {
        const Color sigma = Color(1.f, 0.5f, 2.f) * tau;
        const Color want = Le * Color(std::exp(-sigma.x), std::exp(-sigma.y), std::exp(-sigma.z));
        std::string why;
        EXPECT_TRUE(EveryPixelWithin1Percent(RenderSlabWithLight(sigma, Le), want, &why)) << "tau " << tau << ": " << why;
        EXPECT_FALSE(EveryPixelWithin1Percent(RenderSlabWithLight(sigma + Color(std::log(1.02f)), Le), want, &why))
            << "negative control, tau " << tau;
    }
}

// Light scattered in a medium reaches the camera by free flights, phase-function
// scattering and camera connections through the slab's boundaries: a chromatic,
// absorbing and forward-scattering slab (optical depth 0.7-1.3 across, albedo 0.71-0.86)
// between an emitter and a Lambertian floor (albedo 0.8), seen from the side: the upper half of the
// image holds the emitter seen through the slab and the slab's in-scattering, the lower
// half the floor lit through it. Against path per region and channel: Welch's test at a
// family-wise false-alarm rate of 1e-3 (Bonferroni over the 6 comparisons), each able to
// detect 2 % (limit x standard error < 2 % of the mean), and the negative control -- light
// scaled by 2 % away from path -- must fail it.
TEST(LightMedia, AgreesWithPathThroughAScatteringSlab) {
    SceneDesc d = FloorScene(0.8f, 2.f);
    d.media.push_back({Color(0.2f, 0.1f, 0.3f), Color(0.5f, 0.6f, 1.f), 0.4f});
    AddQuad(d, {-1, 3, -1}, {1, 3, -1}, {1, 3, 1}, {-1, 3, 1}, AddMaterial(d, Color(0.f), Color(4.f)));
    AddOutwardBox(d, {-1.5f, 1, -1.5f}, {1.5f, 2, 1.5f}, AddInterface(d, 0));
    Scene scene(d);
    const uint32_t W = 12, H = 12;
    const Camera side = LookDownMinusZ({0, 1.5f, 5}, W, H, 0.6f);
    constexpr int kRuns = 24, kRegions = 2;
    // mean[integrator][region][channel] over runs, and the variance of the runs' values.
    double mean[2][kRegions][3] = {}, var[2][kRegions][3] = {};
    std::vector<double> values[2][kRegions][3];
    const char* names[2] = {"path", "light"};
    for (int i = 0; i < 2; ++i) {
        RenderOptions opt;
        opt.integrator = names[i];
        opt.spp = 256;
        for (int k = 0; k < kRuns; ++k) {
            opt.seed = 11 + uint32_t(k);
            const std::vector<float> img = RenderResolved(scene, side, opt);
            for (int r = 0; r < kRegions; ++r)
                for (int c = 0; c < 3; ++c) {
                    double sum = 0;
                    for (uint32_t y = r * H / kRegions; y < (r + 1) * H / kRegions; ++y)
                        for (uint32_t x = 0; x < W; ++x) sum += img[4 * (y * W + x) + c];
                    values[i][r][c].push_back(sum / (W * H / kRegions));
                }
        }
        for (int r = 0; r < kRegions; ++r)
            for (int c = 0; c < 3; ++c) {
                for (double v : values[i][r][c]) mean[i][r][c] += v / kRuns;
                for (double v : values[i][r][c]) var[i][r][c] += (v - mean[i][r][c]) * (v - mean[i][r][c]) / (kRuns - 1);
            }
    }
    const double alpha = 1e-3 / (kRegions * 3);
    for (int r = 0; r < kRegions; ++r)
        for (int c = 0; c < 3; ++c) {
            const double mp = mean[0][r][c], ml = mean[1][r][c], vp = var[0][r][c], vl = var[1][r][c];
            EXPECT_GT(mp, 0.01) << "region " << r << " channel " << c;  // not black
            const Welch w = WelchT(ml, vl, kRuns, mp, vp, kRuns);
            const double limit = StudentTCritical(alpha, w.df);
            EXPECT_LT(std::abs(w.t), limit) << "region " << r << " channel " << c << ": light " << ml << " vs path " << mp;
            EXPECT_LT(limit * w.se / mp, 0.02) << "region " << r << " channel " << c << " detects only "
                                               << 100 * limit * w.se / mp << " %";
            const double scale = ml >= mp ? 1.02 : 0.98;
            const Welch biased = WelchT(scale * ml, scale * scale * vl, kRuns, mp, vp, kRuns);
            EXPECT_GT(std::abs(biased.t), StudentTCritical(alpha, biased.df))
                << "negative control: light x " << scale << " passes, region " << r << " channel " << c;
            std::printf("region %d channel %d: light/path %.4f (path %.4f, sd path %.4f light %.4f), detectable %.2f %%\n", r, c, ml / mp, mp, std::sqrt(vp), std::sqrt(vl),
                        100 * limit * w.se / mp);
        }
}
