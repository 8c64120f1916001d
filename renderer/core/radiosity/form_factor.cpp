#include "form_factor.h"

#include <algorithm>
#include <array>
#include <cmath>

namespace tessera {

float PointToPolygonFormFactor(Vec3 x, Vec3 n, const Vec3* poly, size_t k) {
    // Clip to the half-space above x's tangent plane (Sutherland-Hodgman, one plane): the
    // contour formula holds for the part the receiver can see.
    // Clipping adds at most one vertex; triangles (the solvers' case) stay on the stack.
    double stack[8][3];
    std::vector<std::array<double, 3>> heap;
    if (k + 1 > 8) heap.resize(k + 1);
    double (*rel)[3] = k + 1 > 8 ? reinterpret_cast<double (*)[3]>(heap.data()) : stack;
    int m = 0;
    auto height = [&](Vec3 p) { return double(Dot(p - x, n)); };
    for (size_t i = 0; i < k; ++i) {
        const Vec3 a = poly[i], b = poly[(i + 1) % k];
        const double ha = height(a), hb = height(b);
        if (ha > 0.0) {
            rel[m][0] = a.x - x.x, rel[m][1] = a.y - x.y, rel[m][2] = a.z - x.z;
            ++m;
        }
        if ((ha > 0.0) != (hb > 0.0)) {
            const double t = ha / (ha - hb);
            rel[m][0] = (a.x - x.x) + t * (b.x - a.x);
            rel[m][1] = (a.y - x.y) + t * (b.y - a.y);
            rel[m][2] = (a.z - x.z) + t * (b.z - a.z);
            ++m;
        }
    }
    if (m < 3) return 0.f;
    // Lambert: F = (1/2pi) |sum_i gamma_i n . (R_i x R_i+1) / |R_i x R_i+1||, in double:
    // the factor of a far small element is a difference of nearly equal angles.
    double sum = 0.0;
    for (int i = 0; i < m; ++i) {
        const double* a = rel[i];
        const double* b = rel[(i + 1) % m];
        const double c[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
        const double cl = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
        if (!(cl > 0.0)) continue;
        const double dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        const double gamma = std::atan2(cl, dot);
        sum += gamma * (n.x * c[0] + n.y * c[1] + n.z * c[2]) / cl;
    }
    const double f = std::abs(sum) / (2.0 * kPi);
    return static_cast<float>(f);
}

float PointToPolygonFormFactor(Vec3 x, Vec3 n, const std::vector<Vec3>& poly) {
    return PointToPolygonFormFactor(x, n, poly.data(), poly.size());
}

float PointToTriangleFormFactor(Vec3 x, Vec3 n, const Vec3 tri[3]) { return PointToPolygonFormFactor(x, n, tri, 3); }

std::vector<std::array<float, 2>> SubTriangleCentroids(int m) {
    // Upward cells (i+1/3, j+1/3), downward ones (i+2/3, j+2/3), over m.
    std::vector<std::array<float, 2>> out;
    for (int i = 0; i < m; ++i)
        for (int j = 0; i + j < m; ++j) {
            out.push_back({(i + 1.f / 3.f) / m, (j + 1.f / 3.f) / m});
            if (i + j + 1 < m) out.push_back({(i + 2.f / 3.f) / m, (j + 2.f / 3.f) / m});
        }
    return out;
}

float PolygonToPolygonFormFactor(const std::vector<Vec3>& a, const std::vector<Vec3>& b, int cells_per_edge) {
    const Vec3 na = Normalize(Cross(a[1] - a[0], a[2] - a[0]));
    const int c = std::max(1, cells_per_edge);
    const std::vector<std::array<float, 2>> cells = SubTriangleCentroids(c);
    double sum = 0.0, area = 0.0;
    for (size_t t = 1; t + 1 < a.size(); ++t) {
        const Vec3 p0 = a[0], e1 = a[t] - a[0], e2 = a[t + 1] - a[0];
        const double cell_area = 0.5 * Length(Cross(e1, e2)) / (double(c) * c);
        for (const auto& w : cells) {
            sum += double(PointToPolygonFormFactor(p0 + e1 * w[0] + e2 * w[1], na, b)) * cell_area;
            area += cell_area;
        }
    }
    return area > 0.0 ? float(sum / area) : 0.f;
}

// Centroids of the four sub-triangles cut at the edge midpoints (equal areas).
static constexpr float kQuarterCentroids[4][3] = {{2.f / 3.f, 1.f / 6.f, 1.f / 6.f},
                                                  {1.f / 6.f, 2.f / 3.f, 1.f / 6.f},
                                                  {1.f / 6.f, 1.f / 6.f, 2.f / 3.f},
                                                  {1.f / 3.f, 1.f / 3.f, 1.f / 3.f}};

static Vec3 At(const Vec3 t[3], const float w[3]) { return t[0] * w[0] + t[1] * w[1] + t[2] * w[2]; }

float ReceiverMeanFormFactor(const Vec3 rec[3], Vec3 nr, const Vec3 src[3], float Fk[4]) {
    float F = 0.f;
    for (int k = 0; k < 4; ++k) {
        Fk[k] = PointToTriangleFormFactor(At(rec, kQuarterCentroids[k]), nr, src);
        F += 0.25f * Fk[k];
    }
    return F;
}

float VisibleReceiverMeanFormFactor(const Scene& scene, const Vec3 rec[3], Vec3 nr, const Vec3 src[3], Vec3 ns,
                                    float eps, const float Fk[4], int* visible) {
    float FV = 0.f;
    int clear = 0;
    for (int k = 0; k < 4; ++k) {
        if (!(Fk[k] > 0.f)) continue;
        const float* w = kQuarterCentroids[k];
        if (scene.Unoccluded(At(rec, w), eps, nr, At(src, w), eps, ns)) {
            FV += 0.25f * Fk[k];
            ++clear;
        }
    }
    if (visible) *visible = clear;
    return FV;
}

}  // namespace tessera
