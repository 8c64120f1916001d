// The Henyey-Greenstein phase function against its textbook definition:
// p(cos) = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos)^(3/2)), written here in double.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "chi_square.h"
#include "phase.h"
#include "sampler.h"

using namespace tessera;
using tessera::testing::ChiSquareResult;
using tessera::testing::ChiSquareTest;

namespace {

double TextbookHG(double cos_theta, double g) {
    const double denom = 1.0 + g * g - 2.0 * g * cos_theta;
    return (1.0 - g * g) / (4.0 * M_PI * denom * std::sqrt(denom));
}

constexpr int kCosBins = 24, kPhiBins = 8;

// Samples directions scattered from `d` by HG(g_sampled) and bins them over (cos theta,
// phi) about d; expected counts integrate the textbook HG(g_expected) over each bin
// (Simpson, 64 intervals a bin: exact to ~1e-9 of a bin's mass for |g| <= 0.9).
ChiSquareResult HGChiSquare(float g_sampled, double g_expected, Vec3 d, int n = 200000) {
    const HGPhase phase{g_sampled};
    const Frame f = Frame::FromZ(d);
    std::vector<double> observed(kCosBins * kPhiBins, 0.0), expected(kCosBins * kPhiBins, 0.0);
    for (int i = 0; i < n; ++i) {
        PixelSampler s(7, uint64_t(i), 0);
        const PhaseSample ps = phase.Sample(d, s.Get2D());
        const Vec3 l = f.ToLocal(ps.wi);
        double phi = std::atan2(l.y, l.x);
        if (phi < 0) phi += 2 * M_PI;
        const int ic = std::clamp(int((l.z + 1.0) * 0.5 * kCosBins), 0, kCosBins - 1);
        const int ip = std::clamp(int(phi / (2 * M_PI) * kPhiBins), 0, kPhiBins - 1);
        observed[ic * kPhiBins + ip] += 1;
    }
    for (int ic = 0; ic < kCosBins; ++ic) {
        const double a = -1.0 + 2.0 * ic / kCosBins, b = a + 2.0 / kCosBins;
        const int m = 64;
        double sum = 0;
        for (int k = 0; k <= m; ++k) {
            const double w = (k == 0 || k == m) ? 1 : (k % 2 ? 4 : 2);
            sum += w * TextbookHG(a + (b - a) * k / m, g_expected);
        }
        const double mass = sum * (b - a) / (3.0 * m) * 2 * M_PI;  // over all phi
        for (int ip = 0; ip < kPhiBins; ++ip) expected[ic * kPhiBins + ip] = n * mass / kPhiBins;
    }
    return ChiSquareTest(observed, expected);
}

}  // namespace

TEST(HGPhase, ValueIsTheTextbookFormulaAndSamplingPdfMatchesIt) {
    for (float g : {-0.9f, -0.5f, 0.f, 0.3f, 0.7f, 0.9f}) {
        const HGPhase phase{g};
        const Vec3 d = Normalize(Vec3(0.3f, -0.5f, 0.8f));
        for (int i = 0; i < 64; ++i) {
            PixelSampler s(3, uint64_t(i), 0);
            const PhaseSample ps = phase.Sample(d, s.Get2D());
            EXPECT_NEAR(Length(ps.wi), 1.f, 1e-5f);
            const double want = TextbookHG(Dot(d, ps.wi), g);
            EXPECT_NEAR(ps.pdf, want, 2e-4 * want) << "g " << g;
            EXPECT_NEAR(phase.p(d, ps.wi), want, 2e-4 * want) << "g " << g;
        }
    }
}

// Integrates to 1 and has mean cosine g (the definition of g), by quadrature of the
// function under test.
TEST(HGPhase, NormalisedWithMeanCosineG) {
    for (float g : {-0.7f, 0.f, 0.5f, 0.9f}) {
        double total = 0, mean_cos = 0;
        const int m = 20000;
        for (int k = 0; k < m; ++k) {
            const double c = -1.0 + 2.0 * (k + 0.5) / m;
            const double p = HenyeyGreenstein(float(c), g) * 2 * M_PI * (2.0 / m);
            total += p;
            mean_cos += c * p;
        }
        EXPECT_NEAR(total, 1.0, 1e-3) << "g " << g;
        EXPECT_NEAR(mean_cos, g, 2e-3) << "g " << g;
    }
}

// Sampling reproduces the density. The smallest error it detects: sampling with g off by
// 0.02 from the expected density fails (the negative control below), for each g.
TEST(HGPhase, SamplingPassesChiSquare) {
    const Vec3 d = Normalize(Vec3(-0.2f, 0.9f, 0.4f));
    for (float g : {-0.5f, 0.f, 0.3f, 0.7f, 0.9f}) {
        const ChiSquareResult r = HGChiSquare(g, g, d);
        EXPECT_TRUE(r.pass) << "g " << g << ": chi2 " << r.statistic << " dof " << r.dof;
        const double off = g < 0.5f ? g + 0.02 : g - 0.02;
        const ChiSquareResult bad = HGChiSquare(g, off, d);
        EXPECT_FALSE(bad.pass) << "negative control g " << g << " vs " << off << ": chi2 " << bad.statistic;
    }
}
