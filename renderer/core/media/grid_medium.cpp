// Delta and residual ratio tracking through a density grid (grid_medium.h).
#include "grid_medium.h"

#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>

namespace tessera {

void DensityGrid::BuildBlocks() {
    if (nx <= 0 || ny <= 0 || nz <= 0 || density.size() != size_t(nx) * size_t(ny) * size_t(nz))
        throw std::invalid_argument("density grid: " + std::to_string(density.size()) + " values for " +
                                    std::to_string(nx) + " x " + std::to_string(ny) + " x " + std::to_string(nz) +
                                    " voxels");
    for (float v : density)
        if (!(v >= 0.f && std::isfinite(v)))
            throw std::invalid_argument("density grid: densities must be finite and >= 0");
    for (float v : world_to_index)
        if (!std::isfinite(v)) throw std::invalid_argument("density grid: world_to_index is not finite");
    bx = (nx + kBlock - 1) / kBlock;
    by = (ny + kBlock - 1) / kBlock;
    bz = (nz + kBlock - 1) / kBlock;
    block_min.assign(size_t(bx) * by * bz, std::numeric_limits<float>::infinity());
    block_max.assign(size_t(bx) * by * bz, 0.f);
    for (int c = 0; c < bz; ++c)
        for (int b = 0; b < by; ++b)
            for (int a = 0; a < bx; ++a) {
                float lo = std::numeric_limits<float>::infinity(), hi = 0.f;
                // Lookups inside the block touch the voxels one beyond it (clamped at the edge).
                for (int k = c * kBlock - 1; k <= (c + 1) * kBlock; ++k)
                    for (int j = b * kBlock - 1; j <= (b + 1) * kBlock; ++j)
                        for (int i = a * kBlock - 1; i <= (a + 1) * kBlock; ++i) {
                            const float v = Voxel(i, j, k);
                            lo = std::min(lo, v);
                            hi = std::max(hi, v);
                        }
                const size_t idx = (size_t(c) * by + b) * bx + a;
                block_min[idx] = lo;
                block_max[idx] = hi;
            }
}

uint64_t TrackingSeed(Vec3 o, Vec3 d, float u) {
    const float v[7] = {o.x, o.y, o.z, d.x, d.y, d.z, u};
    uint64_t h = 0xCBF29CE484222325ull;
    for (float f : v) {
        uint32_t bits;
        std::memcpy(&bits, &f, sizeof bits);
        h = (h ^ bits) * 0x100000001B3ull;
        h ^= h >> 29;
    }
    return h;
}

MediumSample SampleFreeFlight(const GridMedium& m, Vec3 o, Vec3 d, float t_max, int hero, float u) {
    const DensityGrid& grid = *m.grid;
    TrackingRng rng(TrackingSeed(o, d, u));
    const Vec3 qo = grid.ToIndex(o), qd = grid.DirectionToIndex(d);
    const float k[3] = {m.sigma_s.x, m.sigma_s.y, m.sigma_s.z};
    const float kh = k[hero];
    double majorant_integral = 0.0;  // M: the integral of D_max over the distance flown
    int collisions = 0;
    MediumSample ms;
    ms.t = t_max;
    grid.ForEachBlock(qo, qd, 0.f, t_max, [&](float ta, float tb, float, float dmax) {
        if (!(dmax > 0.f)) return true;
        if (!(kh > 0.f)) {
            majorant_integral += double(dmax) * (tb - ta);
            return true;
        }
        const float mu = kh * dmax;
        for (float t = ta;;) {
            const float dt = -std::log1p(-rng.Uniform()) / mu;
            if (!(t + dt < tb)) {
                majorant_integral += double(dmax) * (tb - t);
                return true;
            }
            t += dt;
            majorant_integral += double(dmax) * dt;
            ++collisions;
            if (rng.Uniform() * dmax < grid.Lookup(qo + qd * t)) {
                ms.scattered = true;
                ms.t = t;
                return false;
            }
        }
    });
    float ratio[3];
    for (int c = 0; c < 3; ++c) {
        if (c == hero) {
            ratio[c] = 1.f;
        } else if (kh > 0.f) {
            ratio[c] = k[c] > 0.f ? float(std::exp(collisions * std::log(double(k[c]) / kh) -
                                                   (double(k[c]) - kh) * majorant_integral))
                                  : (collisions > 0 ? 0.f : float(std::exp(kh * majorant_integral)));
        } else {
            ratio[c] = float(std::exp(-double(k[c]) * majorant_integral));
        }
    }
    ms.pdf = Color(ratio[0], ratio[1], ratio[2]);
    ms.f = ms.pdf * EstimateTransmittance(m, m.sigma_a, o, d, 0.f, ms.t, rng);
    return ms;
}

Color EstimateTransmittance(const GridMedium& m, Color k, Vec3 o, Vec3 d, float t0, float t1, TrackingRng& rng) {
    const float kmax = MaxComponent(k);
    if (!(kmax > 0.f) || !(t1 > t0)) return Color(1.f);
    const DensityGrid& grid = *m.grid;
    const Vec3 qo = grid.ToIndex(o), qd = grid.DirectionToIndex(d);
    const float kk[3] = {k.x, k.y, k.z};
    double control[3] = {0.0, 0.0, 0.0};  // optical depth of each block's minimum, exact
    float w[3] = {1.f, 1.f, 1.f};          // the residual's ratio-tracking weights
    grid.ForEachBlock(qo, qd, t0, t1, [&](float ta, float tb, float dmin, float dmax) {
        for (int c = 0; c < 3; ++c) control[c] += double(kk[c]) * dmin * (tb - ta);
        const float mu = kmax * (dmax - dmin);
        if (!(mu > 0.f)) return true;
        for (float t = ta;;) {
            t += -std::log1p(-rng.Uniform()) / mu;
            if (!(t < tb)) return true;
            const float excess = grid.Lookup(qo + qd * t) - dmin;
            for (int c = 0; c < 3; ++c) w[c] *= std::max(0.f, 1.f - kk[c] * excess / mu);
            if (w[0] == 0.f && w[1] == 0.f && w[2] == 0.f) return false;
        }
    });
    return {w[0] * float(std::exp(-control[0])), w[1] * float(std::exp(-control[1])),
            w[2] * float(std::exp(-control[2]))};
}

}  // namespace tessera
