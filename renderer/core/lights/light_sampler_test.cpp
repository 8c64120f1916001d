#include <gtest/gtest.h>

#include "chi_square.h"
#include "light_sampler.h"
#include "sampler.h"

using namespace tessera;

TEST(LightSampler, ChoosesInProportionToPower) {
    std::vector<double> power = {1.0, 0.0, 5.0, 0.25, 3.0, 0.0, 10.0, 1e-3};
    LightSampler ls(power);
    double total = 0.0;
    for (double p : power) total += p;
    const int n = 2000000;
    std::vector<double> observed(power.size(), 0.0), expected(power.size());
    for (size_t i = 0; i < power.size(); ++i) {
        expected[i] = n * power[i] / total;
        EXPECT_NEAR(ls.Pmf(uint32_t(i)), power[i] / total, 1e-7);
    }
    for (int i = 0; i < n; ++i) {
        PixelSampler s(2, uint64_t(i), 0);
        float pmf;
        uint32_t k = ls.Sample(s.Get1D(), &pmf);
        ASSERT_LT(k, power.size());
        ASSERT_GT(power[k], 0.0) << "an emitter of zero power was chosen";
        ASSERT_EQ(pmf, ls.Pmf(k));
        observed[k] += 1.0;
    }
    auto r = tessera::testing::ChiSquareTest(observed, expected);
    EXPECT_TRUE(r.pass) << "chi2 " << r.statistic << " dof " << r.dof;
}

TEST(LightSampler, EmptyOrAllZeroHasNothingToSample) {
    EXPECT_TRUE(LightSampler(std::vector<double>{}).empty());
    EXPECT_TRUE(LightSampler(std::vector<double>{0.0, 0.0}).empty());
    EXPECT_THROW(LightSampler(std::vector<double>{1.0, -1.0}), std::invalid_argument);
    EXPECT_THROW(LightSampler(std::vector<double>{1.0, NAN}), std::invalid_argument);
}
