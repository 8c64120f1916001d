// Small vector math for the renderer. Vec3 doubles as linear RGB (Color).
#pragma once

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>

namespace tessera {

inline constexpr float kPi = 3.14159265358979323846f;
inline constexpr float kInvPi = 0.31830988618379067154f;
inline constexpr float kInv2Pi = 0.15915494309189533577f;

struct Vec3 {
    float x = 0.f, y = 0.f, z = 0.f;
    constexpr Vec3() = default;
    constexpr Vec3(float x_, float y_, float z_) : x(x_), y(y_), z(z_) {}
    constexpr explicit Vec3(float v) : x(v), y(v), z(v) {}
    float operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
};
using Color = Vec3;  // linear RGB

struct Vec2 {
    float x = 0.f, y = 0.f;
};

inline Vec3 operator+(Vec3 a, Vec3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
inline Vec3 operator-(Vec3 a, Vec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline Vec3 operator-(Vec3 a) { return {-a.x, -a.y, -a.z}; }
inline Vec3 operator*(Vec3 a, Vec3 b) { return {a.x * b.x, a.y * b.y, a.z * b.z}; }
inline Vec3 operator*(Vec3 a, float s) { return {a.x * s, a.y * s, a.z * s}; }
inline Vec3 operator*(float s, Vec3 a) { return a * s; }
inline Vec3 operator/(Vec3 a, float s) { return a * (1.f / s); }
inline Vec3& operator+=(Vec3& a, Vec3 b) { return a = a + b; }
inline Vec3& operator*=(Vec3& a, Vec3 b) { return a = a * b; }
inline Vec3& operator*=(Vec3& a, float s) { return a = a * s; }

inline float Dot(Vec3 a, Vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 Cross(Vec3 a, Vec3 b) {
    return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline float LengthSquared(Vec3 a) { return Dot(a, a); }
inline float Length(Vec3 a) { return std::sqrt(Dot(a, a)); }
inline Vec3 Normalize(Vec3 a) { return a / Length(a); }
inline float MaxComponent(Vec3 a) { return std::max(a.x, std::max(a.y, a.z)); }
inline float MaxAbsComponent(Vec3 a) {
    return std::max(std::abs(a.x), std::max(std::abs(a.y), std::abs(a.z)));
}
inline bool IsBlack(Color c) { return c.x == 0.f && c.y == 0.f && c.z == 0.f; }
inline bool IsFinite(Vec3 a) { return std::isfinite(a.x) && std::isfinite(a.y) && std::isfinite(a.z); }
// Rec. 709 luminance: light power and Russian roulette weigh channels by it.
inline float Luminance(Color c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }

// Orthonormal basis around a unit normal n (Duff et al. 2017, branchless, no singularity).
struct Frame {
    Vec3 s, t, n;
    static Frame FromZ(Vec3 n) {
        float sign = std::copysign(1.f, n.z);
        float a = -1.f / (sign + n.z);
        float b = n.x * n.y * a;
        return {Vec3(1.f + sign * n.x * n.x * a, sign * b, -sign * n.x),
                Vec3(b, sign + n.y * n.y * a, -n.y), n};
    }
    Vec3 ToLocal(Vec3 v) const { return {Dot(v, s), Dot(v, t), Dot(v, n)}; }
    Vec3 FromLocal(Vec3 v) const { return s * v.x + t * v.y + n * v.z; }
};

struct Ray {
    Vec3 o, d;  // d is unit length
};

// Moves a ray origin off a surface along its normal, scaled with the coordinates'
// magnitude because float rounding error in a hit point grows with it.
// gamma_n = n u / (1 - n u), u = 2^-24: the relative error bound of n chained float
// operations (Higham 2002; pbrt-v4 6.8.1).
inline constexpr float Gamma(int n) {
    constexpr float u = std::numeric_limits<float>::epsilon() * 0.5f;
    return (float(n) * u) / (1.f - float(n) * u);
}

// std::nextafter(v, +inf) and (v, -inf), bit for bit (zeros, denormals, infinities, NaN
// included), without the libm call: a float's bits are ordered like its magnitude.
inline float NextFloatUp(float v) {
    if (std::isnan(v) || v == std::numeric_limits<float>::infinity()) return v;
    if (v == 0.f) return std::bit_cast<float>(uint32_t(1));
    const uint32_t bits = std::bit_cast<uint32_t>(v);
    return std::bit_cast<float>(v > 0.f ? bits + 1 : bits - 1);
}
inline float NextFloatDown(float v) {
    if (std::isnan(v) || v == -std::numeric_limits<float>::infinity()) return v;
    if (v == 0.f) return std::bit_cast<float>(uint32_t(0x80000001u));
    const uint32_t bits = std::bit_cast<uint32_t>(v);
    return std::bit_cast<float>(v > 0.f ? bits - 1 : bits + 1);
}

// The origin of a ray leaving a surface point p toward w, where p is known to lie within
// p_error (absolute, per axis) of the true surface with normal n: p is pushed along n past
// the error box's extent along n, so the origin is certainly on w's side of the surface
// (no self-intersection), then one ulp further per axis so that rounding the sum cannot
// pull it back. The offset scales with the surface's own coordinates (p_error), not with
// |p|: a hit near the origin on a huge triangle is offset by that triangle's error, and a
// hit 1e5 from the origin by a few float32 ulps there, not by a fixed fraction of |p|.
inline Vec3 OffsetRayOrigin(Vec3 p, float p_error, Vec3 n, Vec3 w) {
    const float side = Dot(w, n) < 0.f ? -1.f : 1.f;
    const float d = side * p_error * (std::abs(n.x) + std::abs(n.y) + std::abs(n.z));
    auto push = [&](float c, float nc) {
        const float away = nc * side;  // which way this axis moves off the surface
        c += nc * d;
        return away > 0.f ? NextFloatUp(c) : (away < 0.f ? NextFloatDown(c) : c);
    };
    return {push(p.x, n.x), push(p.y, n.y), push(p.z, n.z)};
}

// The relative shortening of a shadow ray whose ends were both moved off their surfaces:
// it only absorbs the intersector's own rounding of t.
inline constexpr float kShadowEpsilon = 1e-4f;

// The point of triangle (p0, p1, p2) at barycentrics (1 - b1 - b2, b1, b2), evaluated as
// p0 + b1 (p1 - p0) + b2 (p2 - p0), and in *p_error the bound of its distance (per axis)
// from the triangle's plane. For any b1, b2 the exact value of that expression lies on the
// plane, so however inaccurate the barycentrics are, only the evaluation's own rounding
// moves the point off it: one rounding of the final sum (relative to |p|) and three of the
// small terms (relative to the edges). The weighted sum b0 p0 + b1 p1 + b2 p2 instead needs
// gamma_7 of sum |b_i p_i| (pbrt-v4 6.8.4), seven times the offset far from the origin,
// where rays leaving a surface must not be moved farther than a pixel's footprint.
inline Vec3 TrianglePoint(Vec3 p0, Vec3 p1, Vec3 p2, float b1, float b2, float* p_error) {
    auto abs3 = [](Vec3 v) { return Vec3(std::abs(v.x), std::abs(v.y), std::abs(v.z)); };
    const Vec3 e1 = p1 - p0, e2 = p2 - p0;
    const Vec3 p = p0 + (e1 * b1 + e2 * b2);
    *p_error = Gamma(2) * MaxAbsComponent(abs3(p)) +
               Gamma(4) * MaxAbsComponent(abs3(e1) * std::abs(b1) + abs3(e2) * std::abs(b2));
    return p;
}

}  // namespace tessera
