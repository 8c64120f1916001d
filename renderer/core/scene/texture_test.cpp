// TextureSet against values worked out by hand from the UsdUVTexture spec: texel centres
// at half-integers, st (0, 0) at the lower-left, wrap modes, scale/bias/fallback, channel
// outputs, sRGB, UsdTransform2d, UDIM tiles.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>

#include "texture.h"

using namespace tessera;

namespace {

Image Grey(uint32_t w, uint32_t h, std::vector<float> v, bool srgb = false) {
    Image im;
    im.width = w;
    im.height = h;
    im.channels = 1;
    im.texels = std::move(v);
    im.srgb = srgb;
    return im;
}

TextureDesc Tex(int32_t image, WrapMode s = WrapMode::kRepeat, WrapMode t = WrapMode::kRepeat) {
    TextureDesc d;
    d.image = image;
    d.wrap_s = s;
    d.wrap_t = t;
    d.output = TextureOutput::kR;
    return d;
}

// One row of two texels, 0.2 and 1.0, under every wrap mode.
float Row(WrapMode mode, float s) {
    TextureSet set({Grey(2, 1, {0.2f, 1.0f})}, {Tex(0, mode, WrapMode::kClamp)});
    return set.EvaluateFloat(0, {s, 0.5f});
}

}  // namespace

TEST(Texture, SrgbDecodeOfKnownValues) {
    EXPECT_FLOAT_EQ(SrgbToLinear(0.f), 0.f);
    EXPECT_FLOAT_EQ(SrgbToLinear(1.f), 1.f);
    // 8-bit 128: ((128/255 + 0.055) / 1.055)^2.4 = 0.215861
    EXPECT_NEAR(SrgbToLinear(128.f / 255.f), 0.215861f, 1e-5f);
    // the linear segment: 10/255 / 12.92
    EXPECT_NEAR(SrgbToLinear(10.f / 255.f), 0.0030353f, 1e-6f);
}

TEST(Texture, TexelCentresAreExactAndBilinearBetweenThem) {
    EXPECT_FLOAT_EQ(Row(WrapMode::kClamp, 0.25f), 0.2f);
    EXPECT_FLOAT_EQ(Row(WrapMode::kClamp, 0.75f), 1.0f);
    EXPECT_FLOAT_EQ(Row(WrapMode::kClamp, 0.5f), 0.6f);
    EXPECT_FLOAT_EQ(Row(WrapMode::kClamp, 0.375f), 0.4f);
}

TEST(Texture, WrapModesOutsideTheUnitSquare) {
    // s = 0: halfway between texel -1 and texel 0.
    EXPECT_NEAR(Row(WrapMode::kRepeat, 0.f), 0.6f, 1e-6f);  // texel -1 is texel 1 (1.0)
    EXPECT_NEAR(Row(WrapMode::kClamp, 0.f), 0.2f, 1e-6f);
    EXPECT_NEAR(Row(WrapMode::kMirror, 0.f), 0.2f, 1e-6f);  // texel -1 mirrors texel 0
    EXPECT_NEAR(Row(WrapMode::kBlack, 0.f), 0.1f, 1e-6f);   // texel -1 is black
    // s = -0.25: the centre of texel -1.
    EXPECT_NEAR(Row(WrapMode::kRepeat, -0.25f), 1.0f, 1e-6f);
    EXPECT_NEAR(Row(WrapMode::kClamp, -0.25f), 0.2f, 1e-6f);
    EXPECT_NEAR(Row(WrapMode::kMirror, -0.25f), 0.2f, 1e-6f);
    EXPECT_NEAR(Row(WrapMode::kBlack, -0.25f), 0.0f, 1e-6f);
    // s = 1.75: the centre of texel 3 (repeat: texel 1; mirror: 3 -> 0; clamp: 1).
    EXPECT_NEAR(Row(WrapMode::kRepeat, 1.75f), 1.0f, 1e-6f);
    EXPECT_NEAR(Row(WrapMode::kMirror, 1.75f), 0.2f, 1e-6f);
    EXPECT_NEAR(Row(WrapMode::kClamp, 1.75f), 1.0f, 1e-6f);
    EXPECT_NEAR(Row(WrapMode::kBlack, 1.75f), 0.0f, 1e-6f);
    // Huge coordinates neither overflow nor lose the mode (repeat: period 1).
    EXPECT_NEAR(Row(WrapMode::kRepeat, 1000.25f), 0.2f, 1e-3f);
    EXPECT_NEAR(Row(WrapMode::kClamp, 1e30f), 1.0f, 1e-6f);
    EXPECT_NEAR(Row(WrapMode::kBlack, -1e30f), 0.0f, 1e-6f);
}

TEST(Texture, TRunsUpFromTheBottomRow) {
    // Rows are stored top to bottom: top 0.9, bottom 0.1.
    TextureSet set({Grey(1, 2, {0.9f, 0.1f})}, {Tex(0, WrapMode::kClamp, WrapMode::kClamp)});
    EXPECT_FLOAT_EQ(set.EvaluateFloat(0, {0.5f, 0.25f}), 0.1f);
    EXPECT_FLOAT_EQ(set.EvaluateFloat(0, {0.5f, 0.75f}), 0.9f);
}

TEST(Texture, ScaleBiasOutputsAndFallback) {
    Image im;
    im.width = im.height = 1;
    im.channels = 4;
    im.texels = {0.1f, 0.2f, 0.3f, 0.4f};
    TextureDesc d = Tex(0);
    d.scale = {2.f, 2.f, 2.f, 3.f};
    d.bias = {-1.f, -1.f, -1.f, 0.5f};
    d.fallback = {7.f, 8.f, 9.f, 10.f};
    std::vector<TextureDesc> ds;
    for (TextureOutput out : {TextureOutput::kR, TextureOutput::kG, TextureOutput::kB, TextureOutput::kA,
                              TextureOutput::kRGB}) {
        d.output = out;
        ds.push_back(d);
    }
    TextureSet set({im}, ds);
    EXPECT_NEAR(set.EvaluateFloat(0, {0.3f, 0.6f}), -0.8f, 1e-6f);
    EXPECT_NEAR(set.EvaluateFloat(1, {0.3f, 0.6f}), -0.6f, 1e-6f);
    EXPECT_NEAR(set.EvaluateFloat(2, {0.3f, 0.6f}), -0.4f, 1e-6f);
    EXPECT_NEAR(set.EvaluateFloat(3, {0.3f, 0.6f}), 1.7f, 1e-6f);
    Color rgb = set.EvaluateColor(4, {0.3f, 0.6f});
    EXPECT_NEAR(rgb.x, -0.8f, 1e-6f);
    EXPECT_NEAR(rgb.z, -0.4f, 1e-6f);
    Color a = set.EvaluateColor(3, {0.3f, 0.6f});  // a scalar output replicates
    EXPECT_NEAR(a.y, 1.7f, 1e-6f);
    // Non-finite st: the fallback, unscaled.
    const float nan = std::numeric_limits<float>::quiet_NaN();
    EXPECT_EQ(set.EvaluateFloat(3, {nan, 0.5f}), 10.f);
    EXPECT_EQ(set.EvaluateColor(4, {0.5f, std::numeric_limits<float>::infinity()}).y, 8.f);
}

TEST(Texture, MissingChannelsFollowTheGreyAndAlphaRules) {
    Image grey = Grey(1, 1, {0.3f});
    Image grey_alpha = Grey(1, 1, {0.3f, 0.6f});
    grey_alpha.channels = 2;
    Image rgb = Grey(1, 1, {0.1f, 0.2f, 0.3f});
    rgb.channels = 3;
    TextureDesc d = Tex(0);
    d.output = TextureOutput::kA;
    TextureDesc g = Tex(0);
    g.output = TextureOutput::kRGB;
    TextureSet set({grey, grey_alpha, rgb}, {d, g, [&] { auto x = d; x.image = 1; return x; }(),
                                             [&] { auto x = d; x.image = 2; return x; }()});
    EXPECT_EQ(set.EvaluateFloat(0, {0.5f, 0.5f}), 1.f);  // no alpha: opaque
    Color c = set.EvaluateColor(1, {0.5f, 0.5f});
    EXPECT_FLOAT_EQ(c.x, 0.3f);
    EXPECT_FLOAT_EQ(c.z, 0.3f);
    EXPECT_FLOAT_EQ(set.EvaluateFloat(2, {0.5f, 0.5f}), 0.6f);
    EXPECT_EQ(set.EvaluateFloat(3, {0.5f, 0.5f}), 1.f);
}

TEST(Texture, SrgbImagesDecodeColourButNotAlpha) {
    Image im = Grey(1, 1, {128.f / 255.f, 1.f, 0.f, 0.5f}, true);
    im.channels = 4;
    TextureDesc rgb = Tex(0);
    rgb.output = TextureOutput::kRGB;
    TextureDesc a = Tex(0);
    a.output = TextureOutput::kA;
    TextureSet set({im}, {rgb, a});
    EXPECT_NEAR(set.EvaluateColor(0, {0.5f, 0.5f}).x, 0.215861f, 1e-5f);
    EXPECT_FLOAT_EQ(set.EvaluateColor(0, {0.5f, 0.5f}).y, 1.f);
    EXPECT_FLOAT_EQ(set.EvaluateFloat(1, {0.5f, 0.5f}), 0.5f);
}

TEST(Texture, Transform2dScalesRotatesThenTranslates) {
    // A 4x4 ramp, so every st gives a different value.
    std::vector<float> v;
    for (int i = 0; i < 16; ++i) v.push_back(float(i) / 15.f);
    TextureDesc plain = Tex(0);
    TextureDesc xf = Tex(0);
    xf.st_scale[0] = 2.f;
    xf.st_scale[1] = 1.f;
    xf.st_rotation_degrees = 90.f;
    xf.st_translation[0] = 0.1f;
    xf.st_translation[1] = 0.05f;
    TextureSet set({Grey(4, 4, v)}, {plain, xf});
    for (Vec2 st : {Vec2{0.1f, 0.2f}, Vec2{0.33f, 0.71f}, Vec2{0.9f, 0.45f}}) {
        // By hand: (s, t) * (2, 1) = (2s, t); rotated 90 deg CCW: (-t, 2s); + (0.1, 0.05).
        Vec2 expected{-st.y + 0.1f, 2.f * st.x + 0.05f};
        EXPECT_NEAR(set.EvaluateFloat(1, st), set.EvaluateFloat(0, expected), 1e-5f) << st.x << " " << st.y;
    }
    // Negative control: without the transform the values differ.
    EXPECT_GT(std::abs(set.EvaluateFloat(0, {0.1f, 0.2f}) - set.EvaluateFloat(1, {0.1f, 0.2f})), 0.05f);
}

TEST(Texture, UdimTilesAndMissingTilesUseTheFallback) {
    TextureDesc d = Tex(-1);
    d.udim_tiles.assign(100, -1);
    d.udim_tiles[0] = 0;   // 1001: u in [0, 1), v in [0, 1)
    d.udim_tiles[1] = 1;   // 1002: u in [1, 2)
    d.udim_tiles[10] = 2;  // 1011: v in [1, 2)
    d.fallback = {0.5f, 0.5f, 0.5f, 0.5f};
    TextureSet set({Grey(2, 2, {0.3f, 0.3f, 0.3f, 0.3f}), Grey(1, 1, {0.7f}), Grey(1, 1, {0.9f})}, {d});
    EXPECT_FLOAT_EQ(set.EvaluateFloat(0, {0.5f, 0.5f}), 0.3f);
    EXPECT_FLOAT_EQ(set.EvaluateFloat(0, {1.5f, 0.5f}), 0.7f);
    EXPECT_FLOAT_EQ(set.EvaluateFloat(0, {0.2f, 1.7f}), 0.9f);
    EXPECT_FLOAT_EQ(set.EvaluateFloat(0, {2.5f, 0.5f}), 0.5f);   // tile 1003 missing
    EXPECT_FLOAT_EQ(set.EvaluateFloat(0, {-0.5f, 0.5f}), 0.5f);  // left of the UDIM range
    EXPECT_FLOAT_EQ(set.EvaluateFloat(0, {10.5f, 0.5f}), 0.5f);  // right of it
}

TEST(Texture, MeanColorIsTheImageAverageOfNonNegativeOutputs) {
    TextureDesc d = Tex(0);
    d.scale = {2.f, 2.f, 2.f, 1.f};
    d.bias = {-0.5f, -0.5f, -0.5f, 0.f};
    // 2 * {0, 0.5, 1, 0.75} - 0.5 = {-0.5 -> 0, 0.5, 1.5, 1.0}: mean 0.75
    TextureSet set({Grey(2, 2, {0.f, 0.5f, 1.f, 0.75f})}, {d});
    EXPECT_NEAR(set.MeanColor(0).x, 0.75f, 1e-6f);
}

TEST(Texture, RejectsBadInputWithAClearError) {
    EXPECT_THROW(TextureSet({Grey(2, 2, {0.f})}, {}), std::invalid_argument);  // too few texels
    Image five = Grey(1, 1, {0, 0, 0, 0, 0});
    five.channels = 5;
    EXPECT_THROW(TextureSet({five}, {}), std::invalid_argument);
    EXPECT_THROW(TextureSet({Grey(1, 1, {0.f})}, {Tex(3)}), std::invalid_argument);  // image out of range
    TextureDesc nan = Tex(0);
    nan.scale[1] = std::numeric_limits<float>::quiet_NaN();
    EXPECT_THROW(TextureSet({Grey(1, 1, {0.f})}, {nan}), std::invalid_argument);
    try {
        TextureSet({Grey(1, 1, {0.f})}, {Tex(7)});
        ADD_FAILURE() << "an image index out of range was accepted";
    } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("image 7"), std::string::npos) << e.what();
    }
    // Non-finite texels are zeroed, not propagated.
    TextureSet set({Grey(1, 1, {std::numeric_limits<float>::infinity()})}, {Tex(0)});
    EXPECT_EQ(set.EvaluateFloat(0, {0.5f, 0.5f}), 0.f);
}

// ZeroOverTriangle is a proof: wherever it says a triangle emits nothing, every lookup in
// the triangle must give 0. Checked against dense lookups over random triangles of a
// sparse image under every wrap mode, with a transform and on UDIM tiles; and it must
// find the black triangles a hand count says are black (it is not trivially "false").
TEST(Texture, ZeroOverTriangleNeverClaimsAnEmittingTriangle) {
    const uint32_t w = 16, h = 8;
    std::vector<float> v(w * h, 0.f);
    v[3 * w + 5] = 1.f;   // one lit texel, row 3, column 5
    v[7 * w + 15] = 0.5f;  // and one at the bottom-right corner (reached across edges)
    std::vector<TextureDesc> descs;
    for (WrapMode m : {WrapMode::kRepeat, WrapMode::kClamp, WrapMode::kMirror, WrapMode::kBlack})
        descs.push_back(Tex(0, m, m));
    TextureDesc xf = Tex(0);
    xf.st_scale[0] = 1.7f;
    xf.st_rotation_degrees = 33.f;
    xf.st_translation[1] = 0.3f;
    descs.push_back(xf);
    TextureDesc udim = Tex(-1);
    udim.udim_tiles.assign(100, -1);
    udim.udim_tiles[0] = 0;
    udim.udim_tiles[11] = 0;
    descs.push_back(udim);
    TextureSet set({Grey(w, h, v)}, descs);
    uint64_t state = 12345;
    auto uniform = [&] {
        state = state * 6364136223846793005ULL + 1442695040888963407ULL;
        return float(state >> 40) / float(1ULL << 24);
    };
    for (uint32_t t = 0; t < descs.size(); ++t) {
        set.PrepareZeroTest(t);
        int claimed = 0;
        for (int k = 0; k < 3000; ++k) {
            const float size = k % 3 == 0 ? 0.02f : (k % 3 == 1 ? 0.15f : 0.6f);
            const Vec2 c{-1.5f + 4.f * uniform(), -1.5f + 4.f * uniform()};
            const Vec2 st[3] = {c, {c.x + size * uniform(), c.y + size * uniform()},
                                {c.x + size * uniform(), c.y - size * uniform()}};
            if (!set.ZeroOverTriangle(t, st)) continue;
            ++claimed;
            for (int i = 0; i <= 12; ++i)
                for (int j = 0; i + j <= 12; ++j) {
                    const float b1 = i / 12.f, b2 = j / 12.f, b0 = 1.f - b1 - b2;
                    const Vec2 p{b0 * st[0].x + b1 * st[1].x + b2 * st[2].x, b0 * st[0].y + b1 * st[1].y + b2 * st[2].y};
                    ASSERT_LE(set.EvaluateFloat(t, p), 0.f) << "texture " << t << " at " << p.x << " " << p.y;
                }
        }
        EXPECT_GT(claimed, 100) << "texture " << t << ": the test proves few triangles black";
    }
    // By hand, repeat: st box [0.05, 0.1] x [0.1, 0.2] reads columns 0..2, rows 5..7
    // (texel centres at half-integers, rows from the top): no lit texel, black; a box over
    // column 5 row 3 (s 0.34, t 0.56) is not.
    const Vec2 black[3] = {{0.05f, 0.1f}, {0.1f, 0.1f}, {0.05f, 0.2f}};
    const Vec2 lit[3] = {{0.33f, 0.55f}, {0.35f, 0.55f}, {0.33f, 0.57f}};
    EXPECT_TRUE(set.ZeroOverTriangle(0, black));
    EXPECT_FALSE(set.ZeroOverTriangle(0, lit));
    // A positive bias lifts everything; non-finite st proves nothing.
    TextureDesc biased = Tex(0);
    biased.bias = {0.01f, 0.01f, 0.01f, 0.f};
    TextureSet lifted({Grey(w, h, v)}, {biased});
    lifted.PrepareZeroTest(0);
    EXPECT_FALSE(lifted.ZeroOverTriangle(0, black));
    const Vec2 nan_st[3] = {{std::numeric_limits<float>::quiet_NaN(), 0.f}, {0.1f, 0.1f}, {0.05f, 0.2f}};
    EXPECT_FALSE(set.ZeroOverTriangle(0, nan_st));
}

namespace {

// A w x w checker of `check`-texel squares, alternating lo and hi (mean (lo + hi) / 2).
Image Checker(uint32_t w, uint32_t check, float lo, float hi) {
    std::vector<float> v(size_t(w) * w);
    for (uint32_t y = 0; y < w; ++y)
        for (uint32_t x = 0; x < w; ++x) v[size_t(y) * w + x] = ((x / check + y / check) % 2) ? hi : lo;
    return Grey(w, w, std::move(v));
}

// Vertical stripes `stripe` texels wide, lo and hi: constant along t.
Image Stripes(uint32_t w, uint32_t stripe, float lo, float hi) {
    std::vector<float> v(size_t(w) * w);
    for (uint32_t y = 0; y < w; ++y)
        for (uint32_t x = 0; x < w; ++x) v[size_t(y) * w + x] = ((x / stripe) % 2) ? hi : lo;
    return Grey(w, w, std::move(v));
}

// The largest |lookup - expected| over a fixed set of st points with one footprint.
float WorstError(const TextureSet& set, TextureFootprint f, float expected) {
    float worst = 0.f;
    for (int i = 0; i < 64; ++i) {
        // Points spread irregularly over the texture, off the texel and check grid.
        const Vec2 st{std::fmod(0.137f + 0.6180339f * float(i), 1.f), std::fmod(0.291f + 0.7548776f * float(i), 1.f)};
        worst = std::max(worst, std::abs(set.EvaluateFloat(0, st, f) - expected));
    }
    return worst;
}

}  // namespace

// A footprint covering many checks reads the checker's average, (lo + hi) / 2, to 1 %. The
// smallest error this detects is a 2 % shift of the average: a checker whose bright squares
// are 0.04 brighter (average 2 % up) fails the same check (negative control), and so do
// point lookups at the same places (the aliasing the filter removes).
TEST(Texture, FilteredLookupOverManyChecksIsTheCheckerAverage) {
    const float lo = 0.1f, hi = 0.9f, mean = 0.5f, tol = 0.01f * mean;
    // 4-texel checks under a 40-texel footprint; 3-texel checks (not a divisor of any
    // level's texel size) under a 150-texel one.
    const struct { uint32_t size, check; float footprint; } cases[] = {{256, 4, 40.f}, {512, 3, 150.f}};
    for (const auto& [size, check, footprint] : cases) {
        const float wide = footprint / float(size);
        TextureSet set({Checker(size, check, lo, hi)}, {Tex(0)});
        EXPECT_LE(WorstError(set, {{wide, 0.f}, {0.f, wide}}, mean), tol) << "checks of " << check;
        // Rotated 30 degrees: the footprint's axes need not follow the texel grid.
        const float c = std::cos(0.5236f) * wide, s = std::sin(0.5236f) * wide;
        EXPECT_LE(WorstError(set, {{c, s}, {-s, c}}, mean), tol) << "checks of " << check;
        // Negative controls: point lookups alias; a 2 % brighter checker is told apart.
        EXPECT_GT(WorstError(set, {}, mean), 10.f * tol);
        TextureSet brighter({Checker(size, check, lo, hi + 0.04f)}, {Tex(0)});
        EXPECT_GT(WorstError(brighter, {{wide, 0.f}, {0.f, wide}}, mean), tol);
    }
}

// A thin footprint averages along its long axis only: across 4-texel vertical stripes it
// reads their average, along them (at a stripe's centre) the stripe's own value. An
// isotropic filter of the long axis's size would read 0.5 in both (the negative control).
TEST(Texture, ThinFootprintAveragesAlongItsLongAxisOnly) {
    TextureSet set({Stripes(256, 4, 0.1f, 0.9f)}, {Tex(0)});
    const float major = 16.f / 256.f, minor = 0.5f / 256.f;
    const float across = set.EvaluateFloat(0, {0.3f, 0.4f}, {{major, 0.f}, {0.f, minor}});
    EXPECT_NEAR(across, 0.5f, 0.005f);
    // s = 2 / 256: the centre of stripe 0 (texels 0..3, value 0.1).
    const float along = set.EvaluateFloat(0, {2.f / 256.f, 0.4f}, {{minor, 0.f}, {0.f, major}});
    EXPECT_NEAR(along, 0.1f, 0.002f);
    const float isotropic = set.EvaluateFloat(0, {2.f / 256.f, 0.4f}, {{major, 0.f}, {0.f, major}});
    EXPECT_GT(std::abs(isotropic - 0.1f), 0.2f);
}

// Under a footprint of at most one texel (magnification) the lookup is the point lookup's
// bilinear value, bit for bit, under every wrap mode and a UsdTransform2d.
TEST(Texture, MagnifiedLookupIsTheBilinearValue) {
    std::vector<float> v(16 * 16);
    for (size_t i = 0; i < v.size(); ++i) v[i] = std::fmod(0.37f * float(i * i % 101), 1.f);
    for (WrapMode mode : {WrapMode::kRepeat, WrapMode::kClamp, WrapMode::kMirror, WrapMode::kBlack}) {
        TextureDesc d = Tex(0, mode, mode);
        d.st_scale[0] = 1.5f;
        d.st_rotation_degrees = 20.f;
        TextureSet set({Grey(16, 16, v)}, {d});
        for (int i = 0; i < 32; ++i) {
            const Vec2 st{-0.3f + 0.051f * float(i), 1.2f - 0.047f * float(i)};
            const TextureFootprint f{{0.5f / 16.f / 1.5f, 0.f}, {0.f, 0.3f / 16.f}};
            EXPECT_EQ(set.EvaluateFloat(0, st, f), set.EvaluateFloat(0, st));
        }
    }
}

// Every level keeps the image's mean, odd sizes included (a level's texels are box averages
// with partial texels weighed by their overlap): a footprint covering the whole image reads
// the mean. An even-only 2 x 2 box on a 3-texel row {0, 0.5, 1} would read 0.625.
TEST(Texture, EveryPyramidLevelKeepsTheImageMean) {
    TextureSet row({Grey(3, 1, {0.f, 0.5f, 1.f})}, {Tex(0, WrapMode::kClamp, WrapMode::kClamp)});
    EXPECT_NEAR(row.EvaluateFloat(0, {0.5f, 0.5f}, {{4.f, 0.f}, {0.f, 4.f}}), 0.5f, 1e-6f);
    std::vector<float> v(37 * 23);
    double sum = 0;
    for (size_t i = 0; i < v.size(); ++i) sum += v[i] = std::fmod(0.61f * float(i % 29), 1.f);
    TextureSet odd({Grey(37, 23, v)}, {Tex(0)});
    EXPECT_NEAR(odd.EvaluateFloat(0, {0.2f, 0.7f}, {{64.f, 0.f}, {0.f, 64.f}}), float(sum / double(v.size())), 1e-5f);
}

// A UDIM lookup filters within its tile: a footprint as wide as the tile next to a brighter
// one still reads its own tile's value.
TEST(Texture, FilteredUdimLookupStaysInItsTile) {
    TextureDesc d = Tex(-1);
    d.udim_tiles.assign(100, -1);
    d.udim_tiles[0] = 0;
    d.udim_tiles[1] = 1;
    TextureSet set({Grey(2, 2, {0.3f, 0.3f, 0.3f, 0.3f}), Grey(2, 2, {0.7f, 0.7f, 0.7f, 0.7f})}, {d});
    EXPECT_FLOAT_EQ(set.EvaluateFloat(0, {0.95f, 0.5f}, {{1.f, 0.f}, {0.f, 1.f}}), 0.3f);
    EXPECT_FLOAT_EQ(set.EvaluateFloat(0, {1.05f, 0.5f}, {{1.f, 0.f}, {0.f, 1.f}}), 0.7f);
}
