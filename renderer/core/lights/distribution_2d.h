// Piecewise-constant 2-D distribution over [0, 1)^2 from a grid of non-negative weights
// (pbrt-v4 A.5.6): a marginal over rows, then a conditional within the chosen row.
// Sample returns a point whose density Pdf() gives; Pdf is proportional to the weight of
// the cell containing the point, normalised over the unit square.
#pragma once

#include <algorithm>
#include <cstdint>
#include <stdexcept>
#include <vector>

#include "math.h"

namespace tessera {

class Distribution2D {
public:
    Distribution2D() = default;
    // weights: height rows of width values, row-major.
    Distribution2D(const std::vector<float>& weights, uint32_t width, uint32_t height)
        : width_(width), height_(height), cdf_rows_(size_t(width + 1) * height), row_sums_(height), cdf_marginal_(height + 1) {
        if (size_t(width) * height != weights.size() || width == 0 || height == 0)
            throw std::invalid_argument("Distribution2D: weights do not match the grid");
        double total = 0.0;
        for (uint32_t y = 0; y < height; ++y) {
            double* cdf = &cdf_rows_[size_t(y) * (width + 1)];
            cdf[0] = 0.0;
            for (uint32_t x = 0; x < width; ++x) cdf[x + 1] = cdf[x] + std::max(0.f, weights[size_t(y) * width + x]);
            row_sums_[y] = cdf[width];
            total += cdf[width];
        }
        total_ = total;
        cdf_marginal_[0] = 0.0;
        for (uint32_t y = 0; y < height; ++y) cdf_marginal_[y + 1] = cdf_marginal_[y] + row_sums_[y];
    }

    bool empty() const { return !(total_ > 0.0); }

    // Density over the unit square (1 for a uniform grid).
    float Pdf(Vec2 p) const {
        if (empty()) return 0.f;
        uint32_t x = std::min(width_ - 1, uint32_t(std::max(0.f, p.x) * float(width_)));
        uint32_t y = std::min(height_ - 1, uint32_t(std::max(0.f, p.y) * float(height_)));
        double w = cdf_rows_[size_t(y) * (width_ + 1) + x + 1] - cdf_rows_[size_t(y) * (width_ + 1) + x];
        return float(w / total_ * double(width_) * double(height_));
    }

    Vec2 Sample(Vec2 u, float* pdf) const {
        // Row from the marginal, then column from the row: each inverts its cdf linearly
        // inside the chosen cell, so the point is uniform within it.
        uint32_t y = Find(cdf_marginal_.data(), height_, u.y * total_);
        double row_lo = cdf_marginal_[y], row_w = row_sums_[y];
        double fy = row_w > 0.0 ? (u.y * total_ - row_lo) / row_w : 0.5;
        const double* cdf = &cdf_rows_[size_t(y) * (width_ + 1)];
        uint32_t x = Find(cdf, width_, u.x * row_w);
        double cell = cdf[x + 1] - cdf[x];
        double fx = cell > 0.0 ? (u.x * row_w - cdf[x]) / cell : 0.5;
        Vec2 p{float((x + std::clamp(fx, 0.0, 0.999999)) / width_), float((y + std::clamp(fy, 0.0, 0.999999)) / height_)};
        *pdf = float(cell / total_ * double(width_) * double(height_));
        return p;
    }

private:
    // Largest i in [0, n) with cdf[i] <= value and a non-empty cell.
    static uint32_t Find(const double* cdf, uint32_t n, double value) {
        uint32_t i = uint32_t(std::upper_bound(cdf, cdf + n + 1, value) - cdf);
        i = i == 0 ? 0 : i - 1;
        i = std::min(i, n - 1);
        while (i > 0 && cdf[i + 1] - cdf[i] <= 0.0) --i;  // landed on an empty trailing cell
        while (i + 1 < n && cdf[i + 1] - cdf[i] <= 0.0) ++i;
        return i;
    }

    uint32_t width_ = 0, height_ = 0;
    std::vector<double> cdf_rows_, row_sums_, cdf_marginal_;
    double total_ = 0.0;
};

}  // namespace tessera
