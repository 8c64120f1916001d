// DielectricBSDF: the properties every kind has (bsdf_checks.h; a lossless interface
// reflects plus transmits exactly 1 in the white furnace), and its delta lobes: the
// discrete choice between reflection and refraction and Snell's law.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "bsdf_checks.h"
#include "dielectric_bsdf.h"
#include "fresnel.h"

using namespace tessera;
using namespace tessera::testing;

namespace {

std::vector<NamedBSDF> DielectricCases(TransportMode mode, bool) {
    std::vector<NamedBSDF> v;
    for (float ior : {1.f, 1.33f, 1.5f, 2.4f})
        for (float r : {0.f, 0.05f, 0.3f, 1.f})
            v.push_back({"dielectric ior=" + std::to_string(ior) + " r=" + std::to_string(r),
                         DielectricBSDF(ior, TrowbridgeReitz::RoughnessToAlpha(r), mode), r == 0.f || ior == 1.f});
    return v;
}

}  // namespace

TEST(DielectricBSDF, SamplingFollowsPdf) { ExpectSamplingFollowsPdf(DielectricCases, 4000); }
TEST(DielectricBSDF, WhiteFurnaceAtMostOne) { ExpectWhiteFurnaceAtMostOne(DielectricCases); }
TEST(DielectricBSDF, SampleAgreesReciprocalAndFinite) { ExpectConsistentReciprocalAndFinite(DielectricCases); }

// The smooth interface chooses reflection with probability R = Fresnel, to 5 sigma of
// 200000 draws (about 0.005 at R = 0.5), and its directions are exact.
TEST(DielectricBSDF, SmoothLobeProbabilities) {
    for (float ior : {1.33f, 1.5f, 2.4f})
        for (float ct : {0.9f, 0.3f, 0.02f, -0.9f, -0.5f}) {
            DielectricBSDF d(ior, 0.f, TransportMode::Radiance);
            Vec3 wo = Dir(ct, 0.5f);
            float R = FrDielectric(ct, ior);
            const int n = 200000;
            int reflected = 0;
            for (int i = 0; i < n; ++i) {
                PixelSampler s(77, uint64_t(i), 0);
                float uc = s.Get1D();
                auto bs = d.Sample_f(wo, uc, s.Get2D());
                ASSERT_TRUE(bs);
                ASSERT_TRUE(bs->is_specular);
                if (!bs->is_transmission) {
                    ++reflected;
                    EXPECT_NEAR(bs->wi.x, -wo.x, 1e-6f);
                    EXPECT_NEAR(bs->wi.z, wo.z, 1e-6f);
                } else {
                    // Snell: n_o sin θo = n_i sin θi, and wi in the plane of incidence.
                    float eta = bs->eta;
                    float sin_o = std::sqrt(1.f - ct * ct), sin_i = std::sqrt(1.f - bs->wi.z * bs->wi.z);
                    EXPECT_NEAR(sin_o, eta * sin_i, 1e-5f);
                    EXPECT_NEAR(eta, ct > 0.f ? ior : 1.f / ior, 1e-6f);
                    EXPECT_LT(bs->wi.z * wo.z, 0.f);
                    EXPECT_NEAR(bs->wi.x * wo.y - bs->wi.y * wo.x, 0.f, 1e-6f);
                }
            }
            double p = double(reflected) / n, sigma = std::sqrt(std::max(R * (1.0 - R), 1e-6) / n);
            EXPECT_NEAR(p, R, 5.0 * sigma + 1e-6) << "ior " << ior << " cos " << ct;
        }
}

// MaterialX transmission at depth 0 (docs/media.md): the tint multiplies every
// transmission, from either side, smooth and rough, and leaves reflection alone; the
// untinted dielectric is the same BSDF bit for bit.
TEST(DielectricBSDF, TintMultipliesTransmissionOnly) {
    const Color tint(0.9f, 0.5f, 0.2f);
    for (float alpha : {0.f, 0.3f})
        for (float ct : {0.8f, -0.9f}) {  // from inside: steep enough to escape (no total reflection)
            const DielectricBSDF clear(1.5f, alpha, TransportMode::Radiance), tinted(1.5f, alpha, TransportMode::Radiance, tint);
            const Vec3 wo = Dir(ct, 0.5f);
            int transmissions = 0, reflections = 0;
            for (int i = 0; i < 256; ++i) {
                PixelSampler s(5, uint64_t(i), 0);
                const float uc = s.Get1D();
                const Vec2 u = s.Get2D();
                auto a = clear.Sample_f(wo, uc, u), b = tinted.Sample_f(wo, uc, u);
                ASSERT_EQ(bool(a), bool(b));
                if (!a) continue;
                EXPECT_EQ(a->wi.z, b->wi.z);
                EXPECT_EQ(a->pdf, b->pdf);
                const Color want = a->is_transmission ? a->f * tint : a->f;
                EXPECT_EQ(b->f.x, want.x);
                EXPECT_EQ(b->f.y, want.y);
                EXPECT_EQ(b->f.z, want.z);
                if (alpha > 0.f) {
                    const Color fa = clear.f(wo, a->wi), fb = tinted.f(wo, a->wi);
                    EXPECT_EQ(fb.y, a->is_transmission ? fa.y * tint.y : fa.y);
                }
                (a->is_transmission ? transmissions : reflections)++;
            }
            EXPECT_GT(transmissions, 0);
            EXPECT_GT(reflections, 0);
        }
}
