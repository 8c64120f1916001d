// Tabulated directional albedo of the GGX reflection lobe (microfacet.h's D and
// height-correlated Smith G, Schlick Fresnel), for energy compensation.
//
// Schlick's Fresnel is linear in (F0, F90), so the single-scattering albedo of a lobe is
//   E(mu) = F0 E1(mu, r) + (F90 - F0) E5(mu, r)
// with E1 = ∫ D G / (4 cosθo cosθi) cosθi dωi (F = 1) and E5 the same weighted by
// (1 - wo·wm)^5; r = sqrt(alpha) is the UsdPreviewSurface roughness. The tables
// (ggx_albedo_table.h) come from renderer/tools/gen_ggx_albedo.py (deterministic
// quadrature over the visible normals); they are bilinear in (t = sqrt(mu), r), and the
// cosine-weighted averages E_avg(r) = 2 ∫ E(mu) mu dmu are the EXACT integrals of that
// interpolant (linear in r between nodes), so layers built from them integrate exactly.
#pragma once

#include <algorithm>
#include <cmath>

#include "ggx_albedo_table.h"

namespace tessera {

struct GGXAlbedo {
    float e1 = 1.f;  // F = 1
    float e5 = 0.f;  // F = (1 - wo·wm)^5
};

// The roughness row of the tables for one alpha (as stored by TrowbridgeReitz): a lobe
// computes it once, not at every lookup (the sqrt and the clamp are the lookup's cost).
struct GGXRoughnessRow {
    int j = 0;
    float fr = 0.f;
};

inline GGXRoughnessRow GGXRowOf(float alpha) {
    using namespace ggx_table;
    const float r = std::sqrt(std::clamp(alpha, 0.f, 1.f)) * float(kNumRough - 1);
    const int j = std::min(int(r), kNumRough - 2);
    return {j, r - float(j)};
}

// mu = |cos θo| in [0, 1].
inline GGXAlbedo LookupGGXAlbedo(float mu, GGXRoughnessRow row) {
    using namespace ggx_table;
    const float t = std::sqrt(std::clamp(mu, 0.f, 1.f)) * float(kNumMu - 1);
    const int i = std::min(int(t), kNumMu - 2), j = row.j;
    const float ft = t - float(i), fr = row.fr;
    auto bilerp = [&](const float (&a)[kNumRough][kNumMu]) {
        float lo = a[j][i] + (a[j][i + 1] - a[j][i]) * ft;
        float hi = a[j + 1][i] + (a[j + 1][i + 1] - a[j + 1][i]) * ft;
        return lo + (hi - lo) * fr;
    };
    return {bilerp(kE1), bilerp(kE5)};
}

inline GGXAlbedo LookupGGXAlbedo(float mu, float alpha) { return LookupGGXAlbedo(mu, GGXRowOf(alpha)); }

// 2 ∫ E(mu) mu dmu of LookupGGXAlbedo's interpolant.
inline GGXAlbedo LookupGGXAverage(float alpha) {
    using namespace ggx_table;
    const auto [j, fr] = GGXRowOf(alpha);
    return {kE1Avg[j] + (kE1Avg[j + 1] - kE1Avg[j]) * fr, kE5Avg[j] + (kE5Avg[j + 1] - kE5Avg[j]) * fr};
}

}  // namespace tessera
