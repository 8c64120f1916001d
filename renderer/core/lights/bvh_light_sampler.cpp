#include "bvh_light_sampler.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace tessera {

namespace {

inline float SafeSqrt(float x) { return std::sqrt(std::max(0.f, x)); }
inline float SafeAcos(float x) { return std::acos(std::clamp(x, -1.f, 1.f)); }
inline Vec3 Min(Vec3 a, Vec3 b) { return {std::min(a.x, b.x), std::min(a.y, b.y), std::min(a.z, b.z)}; }
inline Vec3 Max(Vec3 a, Vec3 b) { return {std::max(a.x, b.x), std::max(a.y, b.y), std::max(a.z, b.z)}; }

// cos(max(0, a - b)) from the cosines and sines of a and b (angles in [0, pi]).
inline float CosOfDifferenceClamped(float cos_a, float sin_a, float cos_b, float sin_b) {
    return cos_a >= cos_b ? 1.f : cos_a * cos_b + sin_a * sin_b;
}

// Below this cosine an emitter's cone is taken to face away: the margin keeps rounding (and
// the bounds' own rounding) from cutting off light at grazing angles.
constexpr float kFacingMargin = 1e-3f;
// The importance's cosine factors never drop below this, so only the emitter-facing test
// above can make a node's importance 0.
constexpr float kMinCosine = 1e-3f;
constexpr int kMaxDepth = 64;  // the trail is a 64-bit word

}  // namespace

float LightBounds::Importance(Vec3 p, Vec3 n) const {
    if (!(phi > 0.f)) return 0.f;
    const Vec3 pc = (lo + hi) * 0.5f;
    const Vec3 to_p = p - pc;
    const float dist2 = LengthSquared(to_p);
    const float radius = 0.5f * Length(hi - lo);
    // Inside the box (or nearly): the box subtends every direction.
    const bool inside = p.x >= lo.x && p.x <= hi.x && p.y >= lo.y && p.y <= hi.y && p.z >= lo.z && p.z <= hi.z;
    const float cos_b = inside || dist2 <= radius * radius ? -1.f : SafeSqrt(1.f - radius * radius / dist2);
    const float sin_b = SafeSqrt(1.f - cos_b * cos_b);
    const Vec3 wi = dist2 > 0.f ? to_p / std::sqrt(dist2) : Vec3(0.f, 0.f, 1.f);  // from the emitters toward p

    // The smallest angle between an emitting normal and a direction from the box to p:
    // theta_w (axis to wi) less the cone's half-angle and the box's angular radius.
    float cos_w = Dot(w, wi);
    if (two_sided) cos_w = std::abs(cos_w);
    const float sin_w = SafeSqrt(1.f - cos_w * cos_w);
    const float sin_o = SafeSqrt(1.f - cos_theta_o * cos_theta_o);
    const float cos_wo = CosOfDifferenceClamped(cos_w, sin_w, cos_theta_o, sin_o);
    const float sin_wo = SafeSqrt(1.f - cos_wo * cos_wo);
    const float cos_emit = CosOfDifferenceClamped(cos_wo, sin_wo, cos_b, sin_b);
    if (cos_emit < -kFacingMargin) return 0.f;  // every emitter faces away from p (Lambertian: cos_e = 0)

    // Distance: no closer than half the box's diagonal, so a point inside a large node does
    // not blow up its weight.
    const float d2 = std::max(dist2, radius);
    float importance = phi * std::max(cos_emit, kMinCosine) / std::max(d2, 1e-30f);
    if (n.x != 0.f || n.y != 0.f || n.z != 0.f) {
        // The receiver's cosine toward the box, at best; either side (a surface may transmit).
        const float cos_i = std::abs(Dot(wi, n));
        const float sin_i = SafeSqrt(1.f - cos_i * cos_i);
        importance *= std::max(CosOfDifferenceClamped(cos_i, sin_i, cos_b, sin_b), kMinCosine);
    }
    return std::isfinite(importance) ? importance : 0.f;
}

LightBounds LightBounds::Triangle(const Vec3 p[3], float phi, bool two_sided) {
    LightBounds b;
    const Vec3 normal = Cross(p[1] - p[0], p[2] - p[0]);
    const float len = Length(normal);
    if (!(len > 0.f) || !std::isfinite(len)) return b;
    b.lo = Min(Min(p[0], p[1]), p[2]);
    b.hi = Max(Max(p[0], p[1]), p[2]);
    b.phi = phi;
    b.w = normal / len;
    b.cos_theta_o = 1.f;
    b.two_sided = two_sided;
    return b;
}

LightBounds LightBounds::Union(const LightBounds& a, const LightBounds& b) {
    if (!(a.phi > 0.f)) return b;
    if (!(b.phi > 0.f)) return a;
    LightBounds u;
    u.lo = Min(a.lo, b.lo);
    u.hi = Max(a.hi, b.hi);
    u.phi = a.phi + b.phi;
    u.two_sided = a.two_sided || b.two_sided;
    // The smallest cone holding both cones (pbrt-v4's DirectionCone Union), widened by a
    // thousandth of a radian against rounding.
    const float theta_a = SafeAcos(a.cos_theta_o), theta_b = SafeAcos(b.cos_theta_o);
    const float theta_d = SafeAcos(Dot(a.w, b.w));
    constexpr float kSlack = 1e-3f;
    if (std::min(theta_d + theta_b, kPi) <= theta_a) {
        u.w = a.w;
        u.cos_theta_o = std::cos(std::min(theta_a + kSlack, kPi));
        return u;
    }
    if (std::min(theta_d + theta_a, kPi) <= theta_b) {
        u.w = b.w;
        u.cos_theta_o = std::cos(std::min(theta_b + kSlack, kPi));
        return u;
    }
    const float theta_o = 0.5f * (theta_a + theta_d + theta_b);
    const Vec3 axis = Cross(a.w, b.w);
    const float axis_len = Length(axis);
    if (theta_o + kSlack >= kPi || !(axis_len > 1e-7f)) {
        u.w = a.w;
        u.cos_theta_o = -1.f;
        return u;
    }
    // Rotate a.w toward b.w by theta_o - theta_a about their common normal (Rodrigues).
    const Vec3 k = axis / axis_len;
    const float theta_r = theta_o - theta_a;
    const float c = std::cos(theta_r), s = std::sin(theta_r);
    const Vec3 r = a.w * c + Cross(k, a.w) * s + k * (Dot(k, a.w) * (1.f - c));
    u.w = Normalize(r);
    u.cos_theta_o = std::cos(theta_o + kSlack);
    return u;
}

BVHLightSampler::BVHLightSampler(const std::vector<LightBounds>& bounds, const std::vector<uint32_t>& ids,
                                 size_t num_emitters) {
    if (bounds.size() != ids.size()) throw std::invalid_argument("BVHLightSampler: bounds and ids differ in size");
    trail_.assign(num_emitters, 0);
    depth_.assign(num_emitters, 255);
    std::vector<uint32_t> order;
    for (uint32_t i = 0; i < bounds.size(); ++i) {
        if (ids[i] >= num_emitters) throw std::invalid_argument("BVHLightSampler: emitter id out of range");
        if (bounds[i].phi > 0.f && std::isfinite(bounds[i].phi)) order.push_back(i);
    }
    if (order.empty()) return;
    nodes_.reserve(2 * order.size());
    Build(order, 0, order.size(), bounds, ids, 0, 0);
}

uint32_t BVHLightSampler::Build(std::vector<uint32_t>& order, size_t begin, size_t end,
                                const std::vector<LightBounds>& bounds, const std::vector<uint32_t>& ids,
                                uint64_t trail, int depth) {
    const uint32_t index = uint32_t(nodes_.size());
    nodes_.emplace_back();
    if (end - begin == 1) {
        const uint32_t id = ids[order[begin]];
        nodes_[index].bounds = bounds[order[begin]];
        nodes_[index].leaf = true;
        nodes_[index].second_child_or_emitter = id;
        trail_[id] = trail;
        depth_[id] = uint8_t(depth);
        return index;
    }
    // Split the centroids at the middle of their widest extent; when that leaves one side
    // empty (or the tree is deep), at the median. Sorting with the index as tie-break makes
    // the tree a function of the input alone, whatever the standard library.
    Vec3 clo(bounds[order[begin]].lo), chi(clo);
    auto centroid = [&](uint32_t i) { return (bounds[i].lo + bounds[i].hi) * 0.5f; };
    for (size_t k = begin; k < end; ++k) {
        const Vec3 c = centroid(order[k]);
        clo = Min(clo, c);
        chi = Max(chi, c);
    }
    const Vec3 extent = chi - clo;
    const int axis = extent.x >= extent.y && extent.x >= extent.z ? 0 : (extent.y >= extent.z ? 1 : 2);
    auto coord = [&](uint32_t i) {
        const Vec3 c = centroid(i);
        return axis == 0 ? c.x : (axis == 1 ? c.y : c.z);
    };
    std::sort(order.begin() + long(begin), order.begin() + long(end), [&](uint32_t a, uint32_t b) {
        const float ca = coord(a), cb = coord(b);
        return ca < cb || (ca == cb && a < b);
    });
    const float middle = axis == 0 ? 0.5f * (clo.x + chi.x) : (axis == 1 ? 0.5f * (clo.y + chi.y) : 0.5f * (clo.z + chi.z));
    size_t mid = begin;
    while (mid < end && coord(order[mid]) < middle) ++mid;
    if (mid == begin || mid == end || depth > kMaxDepth / 2) mid = begin + (end - begin) / 2;
    if (depth + 1 >= kMaxDepth) throw std::runtime_error("BVHLightSampler: tree deeper than 64 levels");
    Build(order, begin, mid, bounds, ids, trail, depth + 1);
    const uint32_t right = Build(order, mid, end, bounds, ids, trail | (uint64_t(1) << depth), depth + 1);
    nodes_[index].second_child_or_emitter = right;
    nodes_[index].bounds = LightBounds::Union(nodes_[index + 1].bounds, nodes_[right].bounds);
    return index;
}

float BVHLightSampler::LeftProbability(uint32_t i, Vec3 p, Vec3 n) const {
    const float il = nodes_[i + 1].bounds.Importance(p, n);
    const float ir = nodes_[nodes_[i].second_child_or_emitter].bounds.Importance(p, n);
    if (!(il + ir > 0.f)) return -1.f;
    return il / (il + ir);
}

bool BVHLightSampler::Sample(float u, Vec3 p, Vec3 n, uint32_t* emitter, float* pmf) const {
    *pmf = 0.f;
    if (nodes_.empty()) return false;
    if (nodes_[0].leaf && !(nodes_[0].bounds.Importance(p, n) > 0.f)) return false;
    uint32_t i = 0;
    float prob = 1.f;
    while (!nodes_[i].leaf) {
        const float pl = LeftProbability(i, p, n);
        if (pl < 0.f) return false;
        if (u < pl) {
            u = std::min(u / pl, 0x1.fffffep-1f);
            prob *= pl;
            i = i + 1;
        } else {
            u = std::min((u - pl) / (1.f - pl), 0x1.fffffep-1f);
            prob *= 1.f - pl;
            i = nodes_[i].second_child_or_emitter;
        }
    }
    if (!(prob > 0.f)) return false;
    *emitter = nodes_[i].second_child_or_emitter;
    *pmf = prob;
    return true;
}

float BVHLightSampler::Pmf(Vec3 p, Vec3 n, uint32_t emitter) const {
    if (emitter >= depth_.size() || depth_[emitter] == 255) return 0.f;
    if (nodes_[0].leaf) return nodes_[0].bounds.Importance(p, n) > 0.f ? 1.f : 0.f;
    const uint64_t trail = trail_[emitter];
    uint32_t i = 0;
    float prob = 1.f;
    for (int d = 0; !nodes_[i].leaf; ++d) {
        const float pl = LeftProbability(i, p, n);
        if (pl < 0.f) return 0.f;
        if (trail & (uint64_t(1) << d)) {
            prob *= 1.f - pl;
            i = nodes_[i].second_child_or_emitter;
        } else {
            prob *= pl;
            i = i + 1;
        }
    }
    return prob;
}

}  // namespace tessera
