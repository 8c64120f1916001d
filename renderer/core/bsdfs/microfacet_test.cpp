// The GGX distribution (microfacet.h): normalisation, Smith masking and visible-normal
// sampling, the ground every microfacet BSDF kind stands on.
#include <gtest/gtest.h>

#include <cmath>

#include "bsdf_checks.h"
#include "microfacet.h"

using namespace tessera;
using namespace tessera::testing;

TEST(Microfacet, DistributionIsNormalized) {
    // ∫ D(m) cos θm dω = 1, integrated in θ on a grid fine enough for alpha = 0.0025.
    for (float alpha : {0.0025f, 0.09f, 0.5f, 1.f}) {
        TrowbridgeReitz d(alpha);
        const int steps = 400000;
        double sum = 0.0, h = 0.5 * kPi / steps;
        for (int i = 0; i < steps; ++i) {
            double th = (i + 0.5) * h;
            sum += d.D(Vec3(float(std::sin(th)), 0.f, float(std::cos(th)))) * std::cos(th) * std::sin(th) * h;
        }
        EXPECT_NEAR(2.0 * kPi * sum, 1.0, 2e-3) << "alpha " << alpha;
    }
}

TEST(Microfacet, VisibleNormalsIntegrateToOne) {
    // ∫ G1(w) max(0, w·m) D(m) / cos θw dm = 1 checks G1 (Λ) against D: the weak white
    // furnace of Heitz 2014. A wrong Λ (e.g. a missing 1/2) fails by tens of percent.
    for (float alpha : {0.09f, 0.5f, 1.f})
        for (float ct : {0.95f, 0.5f, 0.1f}) {
            TrowbridgeReitz d(alpha);
            Vec3 w = Dir(ct, 0.4f);
            const int nt = 1500, np = 600;
            double sum = 0.0;
            for (int i = 0; i < nt; ++i)
                for (int j = 0; j < np; ++j) {
                    double c = (i + 0.5) / nt, phi = 2.0 * kPi * (j + 0.5) / np;
                    double s = std::sqrt(1.0 - c * c);
                    sum += d.PDF(w, Vec3(float(s * std::cos(phi)), float(s * std::sin(phi)), float(c)));
                }
            EXPECT_NEAR(sum * (1.0 / nt) * (2.0 * kPi / np), 1.0, 5e-3) << "alpha " << alpha << " cos " << ct;
        }
}

TEST(Microfacet, SmithMaskingLimits) {
    TrowbridgeReitz d(0.3f);
    EXPECT_FLOAT_EQ(d.G1(Vec3(0, 0, 1)), 1.f);
    EXPECT_EQ(d.G1(Vec3(1, 0, 0)), 0.f);
    EXPECT_EQ(d.G(Vec3(1, 0, 0), Vec3(0, 0, 1)), 0.f);
    for (float a : {0.1f, 0.5f, 0.9f})
        for (float b : {0.05f, 0.5f, 1.f}) {
            Vec3 wo = Dir(a, 0.f), wi = Dir(b, 2.f);
            // Height correlation: G lies between the separable product and either G1.
            EXPECT_LE(d.G(wo, wi), std::min(d.G1(wo), d.G1(wi)) + 1e-6f);
            EXPECT_GE(d.G(wo, wi), d.G1(wo) * d.G1(wi) - 1e-6f);
            EXPECT_NEAR(d.GOverCos(wo, wi) * a * b, d.G(wo, wi), 1e-6f);
        }
    // Roughness 0 is flagged smooth, and its (clamped) alpha stays usable.
    TrowbridgeReitz smooth(TrowbridgeReitz::RoughnessToAlpha(0.f));
    EXPECT_TRUE(smooth.EffectivelySmooth());
    EXPECT_TRUE(std::isfinite(smooth.D(Vec3(0, 0, 1))));
    EXPECT_FALSE(TrowbridgeReitz(TrowbridgeReitz::RoughnessToAlpha(0.05f)).EffectivelySmooth());
}

TEST(Microfacet, VisibleNormalSamplingMatchesPdf) {
    uint32_t seed = 100;
    for (float alpha : {0.0025f, 0.09f, 0.5f, 1.f})
        for (float ct : {1.f, 0.7f, 0.02f, -0.6f}) {
            TrowbridgeReitz d(alpha);
            Vec3 w = Dir(ct, 0.7f);
            auto r = DirectionsChiSquare([&](PixelSampler& s) -> std::optional<Vec3> { return d.Sample_wm(w, s.Get2D()); },
                                         [&](Vec3 m) { return double(d.PDF(w, m)); }, PeakHints(w), ++seed);
            EXPECT_TRUE(r.pass) << "alpha " << alpha << " cos " << ct << ": chi2 " << r.statistic << " dof " << r.dof;
        }
}
