// Pearson chi-square goodness of fit for sampling tests (as in pbrt-v4 and Mitsuba 3).
#pragma once

#include <cmath>
#include <vector>

namespace tessera::testing {

// Upper critical value of chi-square with `dof` degrees of freedom at significance given
// by its standard-normal quantile z (Wilson-Hilferty approximation, accurate for dof > 5).
inline double ChiSquareCritical(int dof, double z) {
    double k = double(dof);
    double t = 1.0 - 2.0 / (9.0 * k) + z * std::sqrt(2.0 / (9.0 * k));
    return k * t * t * t;
}

struct ChiSquareResult {
    double statistic = 0.0;
    int dof = 0;
    bool pass = false;
};

// Bins whose expected count is below 5 are pooled into one, as the test requires.
// z = 4.75 puts the false-failure rate near 1e-6 per test.
inline ChiSquareResult ChiSquareTest(const std::vector<double>& observed, const std::vector<double>& expected,
                                     double z = 4.75) {
    ChiSquareResult r;
    double pooled_obs = 0.0, pooled_exp = 0.0;
    int bins = 0;
    for (size_t i = 0; i < observed.size(); ++i) {
        if (expected[i] < 5.0) {
            pooled_obs += observed[i];
            pooled_exp += expected[i];
            continue;
        }
        double d = observed[i] - expected[i];
        r.statistic += d * d / expected[i];
        ++bins;
    }
    if (pooled_exp >= 5.0) {
        double d = pooled_obs - pooled_exp;
        r.statistic += d * d / pooled_exp;
        ++bins;
    } else if (pooled_obs > 10.0) {
        r.statistic = INFINITY;  // samples where the pdf says there should be (almost) none
    }
    r.dof = bins - 1;
    r.pass = r.dof > 0 && r.statistic < ChiSquareCritical(r.dof, z);
    return r;
}

}  // namespace tessera::testing
