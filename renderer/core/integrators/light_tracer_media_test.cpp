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
    SceneDesc d;
    d.media.push_back({sigma_a, Color(0.f), 0.f});
    const float s = 100.f;
    AddQuad(d, {-s, -s, -3}, {s, -s, -3}, {s, s, -3}, {-s, s, -3}, AddMaterial(d, Color(0.f), Le));
    AddOutwardBox(d, {-50, -50, -2}, {50, 50, -1}, AddInterface(d, 0));
    Scene scene(d);
    RenderOptions opt;
    opt.spp = 4;
    opt.integrator = "light";
    return RenderResolved(scene, LookDownMinusZ({0, 0, 0}, 4, 4, 1e-4f), opt);
}

bool Within1Percent(const std::vector<float>& img, Color expected, std::string* why) {
    for (size_t i = 0; i < img.size() / 4; ++i)
        for (int k = 0; k < 3; ++k)
            if (!(std::abs(img[4 * i + k] / Ch(expected, k) - 1.f) < 0.01f)) {
                *why = "pixel " + std::to_string(i) + " channel " + std::to_string(k) + ": " +
                       std::to_string(img[4 * i + k]) + " vs " + std::to_string(Ch(expected, k));
                return false;
            }
    return true;
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
        EXPECT_TRUE(Within1Percent(RenderSlabWithLight(sigma, Le), want, &why)) << "tau " << tau << ": " << why;
        EXPECT_FALSE(Within1Percent(RenderSlabWithLight(sigma + Color(std::log(1.02f)), Le), want, &why))
            << "negative control, tau " << tau;
    }
}

// Light scattered in a medium reaches the camera by free flights, phase-function
// scattering and camera connections through the slab's boundaries: a chromatic,
// absorbing and forward-scattering slab (optical depth 0.7-1.9 across, albedo 0.71-0.79)
// between an emitter and a Lambertian floor, seen from the side so that the image holds
// the slab's in-scattering, the floor lit through it and the emitter seen through it.
// Against path per channel: Welch's test at a family-wise false-alarm rate of 1e-3 with
// 2 % power (ExpectPathLightBDPTAgree; its negative control scales light by 2 %).
TEST(LightMedia, AgreesWithPathThroughAScatteringSlab) {
    SceneDesc d = FloorScene(0.5f, 2.f);
    d.media.push_back({Color(0.2f, 0.1f, 0.4f), Color(0.5f, 0.6f, 1.5f), 0.4f});
    AddQuad(d, {-1, 3, -1}, {1, 3, -1}, {1, 3, 1}, {-1, 3, 1}, AddMaterial(d, Color(0.f), Color(4.f)));
    AddOutwardBox(d, {-1.5f, 1, -1.5f}, {1.5f, 2, 1.5f}, AddInterface(d, 0));
    Scene scene(d);
    const Camera side = LookDownMinusZ({0, 1.5f, 5}, 12, 12, 0.6f);
    RenderOptions opt;
    opt.spp = 64;
    opt.seed = 11;
    for (int c = 0; c < 3; ++c) ExpectPathLightBDPTAgree(scene, side, opt, c, 16, 0.01, {"light"});
}
