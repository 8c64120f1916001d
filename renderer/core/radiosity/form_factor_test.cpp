// Form factors against closed forms (Howell's catalogue; Siegel & Howell, Thermal
// Radiation Heat Transfer, app. C): parallel and perpendicular rectangles, coaxial disks,
// and reciprocity. The point-to-polygon factor is exact, so the error is the midpoint
// rule's over the receiver: each check allows 1 %, and a negative control (a geometry
// whose closed form differs by 2 %) must fail the same check.
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "form_factor.h"

namespace {

using namespace tessera;
constexpr double kPi = 3.14159265358979323846;
constexpr int kCells = 32;

// Parallel, directly opposed rectangles a x b at distance c (Howell C-11).
double ParallelRectangles(double a, double b, double c) {
    const double X = a / c, Y = b / c;
    const double x1 = 1 + X * X, y1 = 1 + Y * Y;
    return 2.0 / (kPi * X * Y) *
           (std::log(std::sqrt(x1 * y1 / (x1 + Y * Y))) + X * std::sqrt(y1) * std::atan(X / std::sqrt(y1)) +
            Y * std::sqrt(x1) * std::atan(Y / std::sqrt(x1)) - X * std::atan(X) - Y * std::atan(Y));
}

// From a rectangle l x w to a perpendicular one l x h sharing the edge of length l (C-14).
double PerpendicularRectangles(double l, double w, double h) {
    const double H = h / l, W = w / l, H2 = H * H, W2 = W * W, S = H2 + W2;
    const double a = (1 + W2) * (1 + H2) / (1 + S);
    const double b = std::pow(W2 * (1 + S) / ((1 + W2) * S), W2);
    const double c = std::pow(H2 * (1 + S) / ((1 + H2) * S), H2);
    return (W * std::atan(1 / W) + H * std::atan(1 / H) - std::sqrt(S) * std::atan(1 / std::sqrt(S)) +
            0.25 * std::log(a * b * c)) /
           (kPi * W);
}

// Coaxial parallel disks of radii r1 (from) and r2 at distance h (C-41).
double CoaxialDisks(double r1, double r2, double h) {
    const double R1 = r1 / h, R2 = r2 / h, X = 1 + (1 + R2 * R2) / (R1 * R1);
    return 0.5 * (X - std::sqrt(X * X - 4 * (R2 / R1) * (R2 / R1)));
}

std::vector<Vec3> Rect(Vec3 o, Vec3 u, Vec3 v) { return {o, o + u, o + u + v, o + v}; }

// A regular 256-gon of the disk's area (its area error would be 1e-4 otherwise) at
// height z, facing +z or -z.
std::vector<Vec3> Disk(float r, float z, bool up) {
    const int n = 256;
    const double scale = std::sqrt(2 * kPi / (n * std::sin(2 * kPi / n)));
    std::vector<Vec3> p;
    for (int k = 0; k < n; ++k) {
        const double a = 2 * kPi * (up ? k : n - k) / n;
        p.push_back(Vec3(float(r * scale * std::cos(a)), float(r * scale * std::sin(a)), z));
    }
    return p;
}

bool Within(double got, double want, double tol) { return std::abs(got / want - 1) < tol; }

TEST(FormFactor, ParallelRectangles) {
    for (auto [a, b, c] : {std::array<float, 3>{1, 1, 1}, {2, 1, 0.5f}, {1, 3, 2}}) {
        const auto from = Rect({0, 0, 0}, {a, 0, 0}, {0, b, 0});
        const auto to = Rect({0, 0, c}, {0, b, 0}, {a, 0, 0});
        const double f = PolygonToPolygonFormFactor(from, to, kCells), want = ParallelRectangles(a, b, c);
        EXPECT_TRUE(Within(f, want, 0.01)) << a << "x" << b << " at " << c << ": " << f << " vs " << want;
        // Negative control: 5 % farther apart, the closed form moves by > 2 %, and the
        // same check against the original's value fails.
        const double moved = ParallelRectangles(a, b, c * 1.05);
        ASSERT_GT(std::abs(moved / want - 1), 0.02);
        const auto farther = Rect({0, 0, c * 1.05f}, {0, b, 0}, {a, 0, 0});
        EXPECT_FALSE(Within(PolygonToPolygonFormFactor(from, farther, kCells), want, 0.01));
    }
    EXPECT_NEAR(ParallelRectangles(1, 1, 1), 0.19982, 1e-4);  // the tabulated value
}

TEST(FormFactor, PerpendicularRectanglesSharingAnEdge) {
    for (auto [l, w, h] : {std::array<float, 3>{1, 1, 1}, {1, 2, 0.5f}, {2, 1, 3}}) {
        const auto from = Rect({0, 0, 0}, {l, 0, 0}, {0, w, 0});  // z = 0 plane, facing +z
        const auto to = Rect({0, 0, 0}, {0, 0, h}, {l, 0, 0});    // y = 0 plane
        const double f = PolygonToPolygonFormFactor(from, to, kCells), want = PerpendicularRectangles(l, w, h);
        EXPECT_TRUE(Within(f, want, 0.01)) << l << "," << w << "," << h << ": " << f << " vs " << want;
        // The smallest of 10 %, 20 %, ... less height that moves the closed form by 2 %.
        float k = 0.9f;
        while (std::abs(PerpendicularRectangles(l, w, h * k) / want - 1) < 0.02) k -= 0.1f;
        const auto shorter = Rect({0, 0, 0}, {0, 0, h * k}, {l, 0, 0});
        EXPECT_FALSE(Within(PolygonToPolygonFormFactor(from, shorter, kCells), want, 0.01));
    }
    EXPECT_NEAR(PerpendicularRectangles(1, 1, 1), 0.20004, 1e-4);
}

TEST(FormFactor, CoaxialDisks) {
    for (auto [r1, r2, h] : {std::array<float, 3>{1, 1, 1}, {0.5f, 2, 1}, {2, 1, 0.5f}}) {
        const auto from = Disk(r1, 0, true), to = Disk(r2, h, false);
        // The source disk is a fan of 254 thin triangles: 16 cells each are plenty.
        const double f = PolygonToPolygonFormFactor(from, to, 4), want = CoaxialDisks(r1, r2, h);
        EXPECT_TRUE(Within(f, want, 0.01)) << r1 << "," << r2 << "," << h << ": " << f << " vs " << want;
        // The smallest of 10 %, 20 %, ... more distance that moves the closed form by 2 %.
        float k = 1.1f;
        while (std::abs(CoaxialDisks(r1, r2, h * k) / want - 1) < 0.02) k += 0.1f;
        EXPECT_FALSE(Within(PolygonToPolygonFormFactor(from, Disk(r2, h * k, false), 4), want, 0.01));
    }
}

// A_i F_ij = A_j F_ji, each side computed independently (different receivers).
TEST(FormFactor, Reciprocity) {
    const auto a = Rect({0, 0, 0}, {1, 0, 0}, {0, 2, 0});         // area 2
    const auto b = Rect({0, 0, 0}, {0, 0, 0.5f}, {1, 0, 0});      // area 0.5, perpendicular
    const auto c = Rect({0.3f, 0.2f, 1.5f}, {0, 0.7f, 0}, {0.4f, 0, 0});  // offset, parallel, area 0.28
    const double ab = 2 * PolygonToPolygonFormFactor(a, b, kCells), ba = 0.5 * PolygonToPolygonFormFactor(b, a, kCells);
    EXPECT_TRUE(Within(ab, ba, 0.01)) << ab << " vs " << ba;
    const double ac = 2 * PolygonToPolygonFormFactor(a, c, kCells), ca = 0.28 * PolygonToPolygonFormFactor(c, a, kCells);
    EXPECT_TRUE(Within(ac, ca, 0.005)) << ac << " vs " << ca;
}

// The point factor is exact: a point under the centre of a square at height 1, and the
// whole hemisphere (a huge square just above the point) is 1; what lies below the
// receiver's plane is clipped away.
TEST(FormFactor, PointToPolygonIsExact) {
    const auto sq = Rect({-1, -1, 1}, {2, 0, 0}, {0, 2, 0});
    // Unit-distance square of half side 1 seen from below its centre: 4 x (1/(2 pi)) x
    // (x/sqrt(1+x^2) atan(y/sqrt(1+x^2)) + y/sqrt(1+y^2) atan(x/sqrt(1+y^2))), x = y = 1.
    const double want = 4 * (2 / std::sqrt(2.0) * std::atan(1 / std::sqrt(2.0))) / (2 * kPi);
    EXPECT_NEAR(PointToPolygonFormFactor({0, 0, 0}, {0, 0, 1}, sq), want, 1e-6);
    EXPECT_NEAR(PointToPolygonFormFactor({0, 0, 0}, {0, 0, 1}, Rect({-1e4f, -1e4f, 1e-2f}, {2e4f, 0, 0}, {0, 2e4f, 0})),
                1.0, 1e-5);
    const auto straddling = Rect({-1, -1, -1}, {2, 0, 0}, {0, 0, 2});  // vertical, half below
    const auto upper = Rect({-1, -1, 0}, {2, 0, 0}, {0, 0, 1});
    EXPECT_NEAR(PointToPolygonFormFactor({0, 0, 0}, {0, 0, 1}, straddling),
                PointToPolygonFormFactor({0, 0, 0}, {0, 0, 1}, upper), 1e-6);
}

}  // namespace
