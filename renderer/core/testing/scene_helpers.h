// Scene-building and rendering helpers shared by the C++ render tests.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <vector>

#include "integrator.h"
#include "render.h"
#include "scene.h"
#include "splat_film.h"

namespace tessera_test {

using namespace tessera;

inline uint32_t AddMaterial(SceneDesc& d, Color albedo, Color emission, bool two_sided = false) {
    d.materials.push_back({albedo, emission, two_sided});
    return uint32_t(d.materials.size() - 1);
}

// Quad a-b-c-d (counter-clockwise seen from its front, where the normal points).
inline void AddQuad(SceneDesc& d, Vec3 a, Vec3 b, Vec3 c, Vec3 e, uint32_t material) {
    uint32_t base = uint32_t(d.positions.size() / 3);
    for (Vec3 p : {a, b, c, e}) d.positions.insert(d.positions.end(), {p.x, p.y, p.z});
    d.indices.insert(d.indices.end(), {base, base + 1, base + 2, base, base + 2, base + 3});
    d.triangle_material.insert(d.triangle_material.end(), {material, material});
}

// Axis-aligned box [lo, hi], faces wound to face inward.
inline void AddInwardBox(SceneDesc& d, Vec3 lo, Vec3 hi, uint32_t material) {
    Vec3 p[8];
    for (int i = 0; i < 8; ++i) p[i] = Vec3(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z);
    AddQuad(d, p[0], p[1], p[3], p[2], material);  // z = lo, normal +z
    AddQuad(d, p[4], p[6], p[7], p[5], material);  // z = hi, normal -z
    AddQuad(d, p[0], p[4], p[5], p[1], material);  // y = lo, normal +y
    AddQuad(d, p[2], p[3], p[7], p[6], material);  // y = hi, normal -y
    AddQuad(d, p[0], p[2], p[6], p[4], material);  // x = lo, normal +x
    AddQuad(d, p[1], p[5], p[7], p[3], material);  // x = hi, normal -x
}

inline Camera LookDownMinusZ(Vec3 origin, uint32_t w, uint32_t h, float tan_half = 0.5f) {
    return Camera{origin, Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, -1), tan_half, tan_half * h / w, w, h};
}

inline std::vector<float> Render(const Scene& s, const Camera& c, RenderOptions o, TileRect t) {
    std::vector<float> out(size_t(t.width) * t.height * 4);
    RenderStats stats = RenderTile(s, c, o, t, out.data());
    EXPECT_EQ(stats.nonfinite_samples, 0u);
    return out;
}

// A large Lambertian floor (y = 0, facing +y) seen straight down from height h by a narrow
// camera, so every pixel sees a point near the origin.
inline SceneDesc FloorScene(float albedo, float half_size = 1000.f) {
    SceneDesc d;
    uint32_t m = AddMaterial(d, Color(albedo), Color(0.f));
    const float s = half_size;
    AddQuad(d, {-s, 0, -s}, {-s, 0, s}, {s, 0, s}, {s, 0, -s}, m);
    return d;
}

inline Camera LookDownAtOrigin(float h, uint32_t res = 4) {
    // Camera looking along -y with up = -z: a tiny field of view around the origin.
    return Camera{{0, h, 0}, Vec3(1, 0, 0), Vec3(0, 0, -1), Vec3(0, -1, 0), 1e-4f, 1e-4f, res, res};
}

// Renders a whole image with any integrator and adds its splats, normalised as the merge
// does (render.h): the final image.
inline std::vector<float> RenderResolved(const Scene& scene, const Camera& cam, const RenderOptions& opt,
                                  RenderStats* stats_out = nullptr) {
    const uint32_t W = cam.width, H = cam.height;
    std::vector<float> img(size_t(W) * H * 4);
    std::vector<int64_t> splats(size_t(W) * H * 3, 0);
    RenderStats st = RenderTile(scene, cam, opt, {0, 0, W, H}, img.data(), nullptr, splats.data());
    EXPECT_EQ(st.rejected_splats, 0u);
    EXPECT_EQ(st.nonfinite_samples, 0u);
    if (st.light_paths)
        for (size_t i = 0; i < size_t(W) * H; ++i)
            for (int c = 0; c < 3; ++c)
                img[4 * i + c] += float(double(splats[3 * i + c]) / SplatScale(scene.splat_exponent()) * double(W * H) / double(st.light_paths));
    if (stats_out) *stats_out = st;
    return img;
}

// Per channel, the mean of K independent estimates (K >= 2) and its standard error.
struct ChannelEstimate {
    std::array<double, 3> mean{}, stderr_mean{};
};
inline ChannelEstimate MeanAndStandardError(const std::vector<std::array<double, 3>>& runs) {
    ChannelEstimate e;
    const double k = double(runs.size());
    for (int c = 0; c < 3; ++c) {
        double s = 0, s2 = 0;
        for (const auto& m : runs) s += m[c];
        e.mean[c] = s / k;
        for (const auto& m : runs) s2 += (m[c] - e.mean[c]) * (m[c] - e.mean[c]);
        e.stderr_mean[c] = std::sqrt(s2 / (k - 1) / k);
    }
    return e;
}

inline double MeanChannel(const std::vector<float>& px, int c) {
    double sum = 0;
    for (size_t i = 0; i < px.size() / 4; ++i) sum += px[4 * i + c];
    return sum / double(px.size() / 4);
}

// Two-sided Student-t quantile: the x with P(|T| > x) = p for T ~ t(df), by bisection on
// the CDF (Simpson's rule on the density).
inline double StudentTCritical(double p, double df) {
    const double c = std::exp(std::lgamma((df + 1) / 2) - std::lgamma(df / 2)) / std::sqrt(df * kPi);
    auto tail = [&](double x) {  // P(T > x)
        const int n = 4000;
        double h = x / n, s = 0;
        for (int i = 0; i <= n; ++i) {
            double f = c * std::pow(1 + (i * h) * (i * h) / df, -(df + 1) / 2);
            s += f * (i == 0 || i == n ? 1 : (i % 2 ? 4 : 2));
        }
        return 0.5 - s * h / 3;
    };
    double lo = 0, hi = 100;
    for (int i = 0; i < 60; ++i) {
        double mid = (lo + hi) / 2;
        (2 * tail(mid) > p ? lo : hi) = mid;
    }
    return (lo + hi) / 2;
}

// Welch's t statistic of mean(a) - mean(b) from per-run values, with the Welch-Satterthwaite
// degrees of freedom and the standard error of the difference.
struct Welch {
    double t, df, se;
};
inline Welch WelchT(double ma, double va, int na, double mb, double vb, int nb) {
    double sa = va / na, sb = vb / nb, se = std::sqrt(sa + sb);
    return {(ma - mb) / se, (sa + sb) * (sa + sb) / (sa * sa / (na - 1) + sb * sb / (nb - 1)), se};
}

// Path and each of `others` (default: light and bdpt) agree on the image mean of channel c:
// K runs of each with independent seeds (opt.seed + k), each compared with path by Welch's
// t at a family-wise false-alarm rate of 1e-3 (Bonferroni over the comparisons). Power:
// each comparison must detect a relative difference of 2 % (limit x standard error / mean),
// and the negative control -- the same comparison with the other integrator scaled by 2 %
// away from path -- must fail; the path mean must exceed min_mean. Returns the worst
// detectable relative difference.
inline double ExpectPathLightBDPTAgree(const Scene& scene, const Camera& cam, RenderOptions opt, int c, int K,
                                       double min_mean,
                                       const std::vector<const char*>& others = {"light", "bdpt"}) {
    std::vector<const char*> order{"path"};
    order.insert(order.end(), others.begin(), others.end());
    const size_t n = order.size();
    std::vector<double> mean(n, 0.0), var(n, 0.0);
    for (size_t i = 0; i < n; ++i) {
        std::vector<double> x;
        RenderOptions o = opt;
        o.integrator = order[i];
        const IntegratorInfo* info = FindIntegrator(order[i]);
        for (int k = 0; k < K; ++k) {
            o.seed = opt.seed + uint32_t(k);
            if (info && info->scene_passes) o.scene_product = RunScenePass(scene, o, 0);
            x.push_back(MeanChannel(RenderResolved(scene, cam, o), c));
        }
        for (double v : x) mean[i] += v / K;
        for (double v : x) var[i] += (v - mean[i]) * (v - mean[i]) / (K - 1);
    }
    EXPECT_GT(mean[0], min_mean);  // not a black image
    const double alpha = 1e-3 / double(n - 1);
    double worst = 0;
    for (size_t i = 1; i < n; ++i) {
        Welch w = WelchT(mean[i], var[i], K, mean[0], var[0], K);
        const double limit = StudentTCritical(alpha, w.df);
        EXPECT_LT(std::abs(w.t), limit) << "integrator " << order[i] << ": " << mean[i] << " vs path "
                                        << mean[0] << " (t = " << w.t << ", df " << w.df << ")";
        const double detectable = limit * w.se / mean[0];
        worst = std::max(worst, detectable);
        EXPECT_LT(detectable, 0.02) << "integrator " << order[i] << " detects only " << 100 * detectable << " %";
        const double scale = mean[i] >= mean[0] ? 1.02 : 0.98;
        Welch biased = WelchT(scale * mean[i], scale * scale * var[i], K, mean[0], var[0], K);
        EXPECT_GT(std::abs(biased.t), StudentTCritical(alpha, biased.df))
            << "integrator " << order[i] << " x " << scale << " passes (t = " << biased.t << ")";
    }
    std::printf("worst detectable relative difference: %.2f %%\n", 100 * worst);
    return worst;
}

}  // namespace tessera_test
