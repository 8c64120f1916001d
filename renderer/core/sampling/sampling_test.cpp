#include <gtest/gtest.h>

#include <set>

#include "chi_square.h"
#include "sampler.h"
#include "sampling.h"

using namespace tessera;
using tessera::testing::ChiSquareTest;

TEST(PixelSampler, IsAPureFunctionOfSeedPixelSampleDimension) {
    PixelSampler a(7, 1234, 5), b(7, 1234, 5);
    for (int d = 0; d < 64; ++d) EXPECT_EQ(a.Get1D(), b.Get1D());
    // Changing any one input changes the stream.
    PixelSampler ref(7, 1234, 5), other_seed(8, 1234, 5), other_pixel(7, 1235, 5), other_sample(7, 1234, 6);
    float r = ref.Get1D();
    EXPECT_NE(r, other_seed.Get1D());
    EXPECT_NE(r, other_pixel.Get1D());
    EXPECT_NE(r, other_sample.Get1D());
}

TEST(PixelSampler, ValuesAreUniformInUnitInterval) {
    const int bins = 64, n = 640000;
    std::vector<double> observed(bins, 0.0), expected(bins, double(n) / bins);
    for (int i = 0; i < n; ++i) {
        PixelSampler s(3, uint64_t(i) * 7919u, uint32_t(i % 17));
        float u = s.Get1D();
        ASSERT_GE(u, 0.f);
        ASSERT_LT(u, 1.f);
        observed[std::min(bins - 1, int(u * bins))] += 1.0;
    }
    auto r = ChiSquareTest(observed, expected);
    EXPECT_TRUE(r.pass) << "chi2 " << r.statistic << " dof " << r.dof;
}

TEST(PixelSampler, ConsecutiveDimensionsAreIndependent) {
    // 2-D histogram of (dim k, dim k+1) pairs must be uniform.
    const int bins = 16, n = 512000;
    std::vector<double> observed(bins * bins, 0.0), expected(bins * bins, double(n) / (bins * bins));
    for (int i = 0; i < n; ++i) {
        PixelSampler s(11, uint64_t(i), 0);
        Vec2 u = s.Get2D();
        observed[int(u.y * bins) * bins + int(u.x * bins)] += 1.0;
    }
    auto r = ChiSquareTest(observed, expected);
    EXPECT_TRUE(r.pass) << "chi2 " << r.statistic << " dof " << r.dof;
}

// Histogram of directions over (cos theta, phi) bins against the exact integral of the
// pdf over each bin, bin_integral(cos0, cos1, phi0, phi1), since d(omega) = d(cos) d(phi).
template <typename SampleFn, typename BinIntegralFn>
void ExpectDirectionsFollowPdf(SampleFn sample, BinIntegralFn bin_integral, const char* name) {
    const int n_theta = 20, n_phi = 40, n = 1000000;
    std::vector<double> observed(n_theta * n_phi, 0.0), expected(n_theta * n_phi, 0.0);
    for (int i = 0; i < n; ++i) {
        PixelSampler s(1, uint64_t(i), 0);
        Vec3 w = sample(s.Get2D());
        ASSERT_NEAR(Length(w), 1.f, 1e-4f) << name;
        float ct = std::clamp(w.z, -1.f, 1.f);
        float phi = std::atan2(w.y, w.x);
        if (phi < 0.f) phi += 2.f * kPi;
        int it = std::min(n_theta - 1, int((ct + 1.f) * 0.5f * n_theta));
        int ip = std::min(n_phi - 1, int(phi / (2.f * kPi) * n_phi));
        observed[it * n_phi + ip] += 1.0;
    }
    for (int it = 0; it < n_theta; ++it)
        for (int ip = 0; ip < n_phi; ++ip) {
            double c0 = -1.0 + 2.0 * it / n_theta, c1 = -1.0 + 2.0 * (it + 1) / n_theta;
            double p0 = 2.0 * kPi * ip / n_phi, p1 = 2.0 * kPi * (ip + 1) / n_phi;
            expected[it * n_phi + ip] = n * bin_integral(c0, c1, p0, p1);
        }
    auto r = ChiSquareTest(observed, expected);
    EXPECT_TRUE(r.pass) << name << ": chi2 " << r.statistic << " dof " << r.dof;
}

TEST(Warps, CosineHemisphereMatchesItsPdf) {
    // integral of cos/pi over the bin = (c1^2 - c0^2) / 2 * dphi / pi, for c >= 0
    ExpectDirectionsFollowPdf([](Vec2 u) { return SampleCosineHemisphere(u); },
                              [](double c0, double c1, double p0, double p1) {
                                  c0 = std::max(c0, 0.0), c1 = std::max(c1, 0.0);
                                  return (c1 * c1 - c0 * c0) / 2.0 * (p1 - p0) / kPi;
                              },
                              "cosine hemisphere");
    for (float u : {0.f, 0.5f, 0.999999f}) EXPECT_NEAR(CosineHemispherePdf(SampleCosineHemisphere({u, 0.3f}).z) * kPi,
                                                     SampleCosineHemisphere({u, 0.3f}).z, 1e-6f);
}

TEST(Warps, UniformConeMatchesItsPdf) {
    for (float sin2 : {0.9f, 0.3f, 0.0005f}) {
        double omc = ConeOneMinusCos(sin2);
        ExpectDirectionsFollowPdf([omc](Vec2 u) { return SampleUniformCone(u, float(omc)); },
                                  [omc](double c0, double c1, double p0, double p1) {
                                      double overlap = std::max(0.0, std::min(c1, 1.0) - std::max(c0, 1.0 - omc));
                                      return overlap * (p1 - p0) / (2.0 * kPi * omc);
                                  },
                                  "uniform cone");
    }
}

TEST(Warps, ConeOneMinusCosIsAccurateForTinyCones) {
    // Against a double-precision reference at small and moderate angles.
    for (double sin2 : {1e-12, 1e-8, 1e-4, 9e-4, 1.1e-3, 0.5, 0.99}) {
        double ref = sin2 / (1.0 + std::sqrt(1.0 - sin2));  // 1 - cos without cancellation
        EXPECT_NEAR(ConeOneMinusCos(float(sin2)) / ref, 1.0, 1e-5) << sin2;
    }
}

TEST(Warps, UniformTriangleBarycentricsAreUniform) {
    // Sample the triangle (0,0),(1,0),(0,1); bin the unit square; bins fully inside get
    // equal counts, and nothing lands outside.
    const int bins = 16, n = 800000;
    std::vector<double> observed(bins * bins, 0.0), expected(bins * bins, 0.0);
    for (int i = 0; i < n; ++i) {
        PixelSampler s(5, uint64_t(i), 0);
        Vec3 b = SampleUniformTriangle(s.Get2D());
        ASSERT_GE(b.x, 0.f);
        ASSERT_GE(b.y, 0.f);
        ASSERT_GE(b.z, -1e-6f);
        float x = b.y, y = b.z;  // point = b1 * (1,0) + b2 * (0,1)
        observed[std::min(bins - 1, int(y * bins)) * bins + std::min(bins - 1, int(x * bins))] += 1.0;
    }
    for (int iy = 0; iy < bins; ++iy)
        for (int ix = 0; ix < bins; ++ix) {
            double cell = 1.0 / (bins * bins);
            if (ix + iy + 2 <= bins) expected[iy * bins + ix] = n * cell / 0.5;          // inside
            else if (ix + iy + 1 == bins) expected[iy * bins + ix] = n * 0.5 * cell / 0.5;  // on the diagonal
        }
    auto r = ChiSquareTest(observed, expected);
    EXPECT_TRUE(r.pass) << "chi2 " << r.statistic << " dof " << r.dof;
}

TEST(Mis, PowerHeuristicWeightsSumToOne) {
    for (float a : {0.f, 1e-8f, 0.3f, 1.f, 7.f, 1e8f})
        for (float b : {1e-8f, 0.3f, 1.f, 7.f, 1e8f}) EXPECT_NEAR(PowerHeuristic(a, b) + PowerHeuristic(b, a), 1.f, 1e-6f);
    EXPECT_EQ(PowerHeuristic(INFINITY, 1.f), 1.f);
}

// Owen-scrambled Sobol: the first 2^k samples of a pixel's 2-D dimension form a (0, k, 2)-net
// (exactly one point in every elementary interval of area 2^-k), for every dimension, pixel
// and seed; and 1-D dimensions put one sample in each of 2^k equal strata.
TEST(OwenSobol, EveryPrefixOfPowerOfTwoLengthIsANet) {
    for (uint64_t pixel : {0ull, 17ull, 123456789ull})
        for (int dim = 0; dim < 6; ++dim)
            for (int k : {2, 4, 6, 8}) {
                const uint32_t n = 1u << k;
                for (int split = 0; split <= k; ++split) {  // intervals of 2^-split x 2^-(k-split)
                    std::vector<int> count(n, 0);
                    for (uint32_t i = 0; i < n; ++i) {
                        PixelSampler s(3, pixel, i, 0, SamplerKind::kOwenSobol);
                        for (int skip = 0; skip < dim; ++skip) s.Get2D();
                        Vec2 u = s.Get2D();
                        uint32_t cx = uint32_t(u.x * float(1u << split)), cy = uint32_t(u.y * float(1u << (k - split)));
                        ++count[(cy << split) | cx];
                    }
                    for (int c : count) ASSERT_EQ(c, 1) << "pixel " << pixel << " dim " << dim << " k " << k;
                }
                std::vector<int> strata(n, 0);
                for (uint32_t i = 0; i < n; ++i) {
                    PixelSampler s(3, pixel, i, 0, SamplerKind::kOwenSobol);
                    for (int skip = 0; skip < dim; ++skip) s.Get1D();
                    ++strata[uint32_t(s.Get1D() * float(n))];
                }
                for (int c : strata) ASSERT_EQ(c, 1);
            }
}

TEST(OwenSobol, AlignedPassesAreNetsToo) {
    // Samples [64, 128) (a second pass) are stratified like the first 64.
    std::vector<int> count(64, 0);
    for (uint32_t i = 64; i < 128; ++i) {
        PixelSampler s(9, 42, i, 0, SamplerKind::kOwenSobol);
        Vec2 u = s.Get2D();
        ++count[uint32_t(u.y * 8.f) * 8 + uint32_t(u.x * 8.f)];
    }
    for (int c : count) EXPECT_EQ(c, 1);
}

TEST(OwenSobol, PixelsAndDimensionsAreDecorrelated) {
    // Across many pixels, a sample's values in dimensions 0 and 1 (and the same dimension
    // in neighbouring pixels) are uncorrelated: |r| ~ 1/sqrt(n).
    const int n = 20000;
    double sxy = 0, sxz = 0, sx = 0, sy = 0, sz = 0, sxx = 0, syy = 0, szz = 0;
    for (int p = 0; p < n; ++p) {
        PixelSampler a(1, uint64_t(p), 5, 0, SamplerKind::kOwenSobol), b(1, uint64_t(p) + 1, 5, 0, SamplerKind::kOwenSobol);
        double x = a.Get1D(), y = a.Get1D(), z = b.Get1D();
        sx += x, sy += y, sz += z, sxy += x * y, sxz += x * z, sxx += x * x, syy += y * y, szz += z * z;
    }
    auto corr = [n](double sab, double sa, double sb, double saa, double sbb) {
        double cov = sab / n - sa / n * sb / n;
        return cov / std::sqrt((saa / n - sa * sa / n / n) * (sbb / n - sb * sb / n / n));
    };
    EXPECT_LT(std::abs(corr(sxy, sx, sy, sxx, syy)), 0.04);
    EXPECT_LT(std::abs(corr(sxz, sx, sz, sxx, szz)), 0.04);
}

TEST(OwenSobol, ValuesAreUniformOverPixels) {
    const int bins = 64, n = 256000;
    std::vector<double> observed(bins, 0.0), expected(bins, double(n) / bins);
    for (int i = 0; i < n; ++i) {
        PixelSampler s(3, uint64_t(i), uint32_t(i % 7), 0, SamplerKind::kOwenSobol);
        float u = s.Get1D();
        ASSERT_GE(u, 0.f);
        ASSERT_LT(u, 1.f);
        observed[std::min(bins - 1, int(u * bins))] += 1.0;
    }
    auto r = ChiSquareTest(observed, expected);
    EXPECT_TRUE(r.pass) << "chi2 " << r.statistic << " dof " << r.dof;
}

// The fast forms (bswap; byte tables) against the definitions, bit by bit, on the values
// the sampler feeds them: small indices and full-width scrambled ones.
TEST(OwenSobol, FastBitReverseAndDimension1MatchTheirDefinitions) {
    auto reverse = [](uint32_t v) {
        uint32_t r = 0;
        for (int b = 0; b < 32; ++b) r |= ((v >> b) & 1u) << (31 - b);
        return r;
    };
    auto dimension1 = [](uint32_t index) {  // one direction number per set bit (Joe & Kuo, dimension 2)
        uint32_t result = 0;
        for (uint32_t v = 1u << 31; index; index >>= 1, v ^= v >> 1)
            if (index & 1u) result ^= v;
        return result;
    };
    // The first points of Sobol's second dimension in index (not Gray-code) order, as
    // pbrt-v4's SobolSample gives them: 0, 1/2, 3/4, 1/4, 5/8, 1/8, 3/8, 7/8.
    const double published[8] = {0, 0.5, 0.75, 0.25, 0.625, 0.125, 0.375, 0.875};
    for (uint32_t i = 0; i < 8; ++i) EXPECT_EQ(SobolDimension1(i) * 0x1p-32, published[i]) << i;
    uint64_t state = 0x1234;
    for (uint32_t i = 0; i < 200000; ++i) {
        const uint32_t v = i < 4096 ? i : uint32_t(Mix64(state += 0x9E3779B97F4A7C15ull));
        ASSERT_EQ(ReverseBits32(v), reverse(v)) << v;
        ASSERT_EQ(SobolDimension1(v), dimension1(v)) << v;
    }
    // Control: the check tells a one-bit difference apart.
    EXPECT_NE(SobolDimension1(0x80000000u), dimension1(0x40000000u));
}

// The sampler skips reversals that cancel; its values must be those of the definition,
// written out here with bit loops: dimension d of sample s is Owen-scrambled Sobol point
// s' = Scramble(s, lo(h)) in (dimension 0, dimension 1), each scrambled with its own seed,
// h = Mix64(pixel key + d * K) (and Mix64(h) for the second coordinate).
TEST(OwenSobol, ValuesEqualTheDefinitionBitForBit) {
    auto reverse = [](uint32_t v) {
        uint32_t r = 0;
        for (int b = 0; b < 32; ++b) r |= ((v >> b) & 1u) << (31 - b);
        return r;
    };
    auto dimension1 = [](uint32_t index) {
        uint32_t result = 0;
        for (uint32_t v = 1u << 31; index; index >>= 1, v ^= v >> 1)
            if (index & 1u) result ^= v;
        return result;
    };
    auto scramble = [&](uint32_t v, uint32_t seed) {  // Burley 2020, on the reversed word
        v = reverse(v);
        v ^= v * 0x3d20adeau;
        v += seed;
        v *= (seed >> 16) | 1u;
        v ^= v * 0x05526c56u;
        v ^= v * 0x53a22864u;
        return reverse(v);
    };
    auto unit = [](uint32_t bits) { return float(bits >> 8) * 0x1p-24f; };
    int mismatches = 0, control_mismatches = 0, checked = 0;
    for (uint32_t seed : {0u, 7u, 0xFFFFFFFFu})
        for (uint64_t pixel : {uint64_t(0), uint64_t(12345), uint64_t(1) << 40})
            for (uint32_t sample : {0u, 1u, 5u, 1023u, 65537u, 0x80000000u}) {
                const uint32_t stream = sample & 1u;
                const uint64_t pixel_key = Mix64(Mix64(seed + 0x6A09E667F3BCC909ull + (uint64_t(stream) << 32)) ^ pixel);
                PixelSampler s(seed, pixel, sample, stream, SamplerKind::kOwenSobol);
                for (uint64_t d = 1; d <= 12; ++d) {
                    const uint64_t h = Mix64(pixel_key + d * 0xD1B54A32D192ED03ull);
                    const uint32_t index = scramble(sample, uint32_t(h));
                    const float x = unit(scramble(reverse(index), uint32_t(h >> 32)));
                    const float y = unit(scramble(dimension1(index), uint32_t(Mix64(h))));
                    // Control: the same point with the other scramble seed for its first
                    // coordinate, which any mix-up of the seeds would give.
                    const float x_swapped = unit(scramble(reverse(index), uint32_t(Mix64(h))));
                    if (d % 3 == 0) {
                        const float u = s.Get1D();
                        mismatches += u != x;
                        control_mismatches += u != x_swapped;
                    } else {
                        const Vec2 u = s.Get2D();
                        mismatches += u.x != x || u.y != y;
                        control_mismatches += u.x != x_swapped;
                    }
                    ++checked;
                }
            }
    EXPECT_EQ(mismatches, 0) << "of " << checked;
    EXPECT_GT(control_mismatches, checked * 9 / 10) << "the check cannot tell the seeds apart";
}
