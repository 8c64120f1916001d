// The hand-written float helpers of math.h against the standard library.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <limits>
#include <vector>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "chi_square.h"
#include "render.h"
#include "splat_film.h"
#include "scene.h"
#include "scene_helpers.h"

using namespace tessera;
using namespace tessera_test;

// The hand-written ulp steps against libm's nextafter, bit for bit, over the cases that
// differ in kind (zeros, denormals, the largest finite, infinities, NaN) and random floats.
TEST(Math, NextFloatUpAndDownAreNextafterBitForBit) {
    const float inf = std::numeric_limits<float>::infinity();
    std::vector<float> values = {0.f, -0.f, std::numeric_limits<float>::denorm_min(),
                                 -std::numeric_limits<float>::denorm_min(), std::numeric_limits<float>::min(),
                                 std::numeric_limits<float>::max(), -std::numeric_limits<float>::max(), inf, -inf,
                                 1.f, -1.f, 1e-30f, -3e7f};
    uint64_t state = 7;
    for (int i = 0; i < 100000; ++i) {
        state = state * 6364136223846793005ull + 1442695040888963407ull;
        values.push_back(std::bit_cast<float>(uint32_t(state >> 32)));
    }
    for (float v : values) {
        const float up = NextFloatUp(v), down = NextFloatDown(v);
        if (std::isnan(v)) {
            ASSERT_TRUE(std::isnan(up) && std::isnan(down));
            continue;
        }
        ASSERT_EQ(std::bit_cast<uint32_t>(up), std::bit_cast<uint32_t>(std::nextafter(v, inf))) << v;
        ASSERT_EQ(std::bit_cast<uint32_t>(down), std::bit_cast<uint32_t>(std::nextafter(v, -inf))) << v;
    }
    // Control: one ulp is told apart.
    EXPECT_NE(NextFloatUp(1.f), 1.f);
}
