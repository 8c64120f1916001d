// Chooses an emitter for a shading point by a bounding volume hierarchy over the emitters'
// positions and orientations (after pbrt-v4's BVHLightSampler, Conty & Kulla 2018): each
// node bounds its emitters' box, total power and the cone of their normals, and a sample
// walks from the root to one leaf, taking each child with probability proportional to an
// importance that bounds what the child can deliver at the point: power, over distance
// squared, times the best cosine the box and the cone allow at the emitter and at the
// receiving surface. Thousands of small emitters then cost a point no more than the few
// near it that face it.
//
// Invariants: the probabilities of all emitters at one point sum to at most 1 (a node's
// bound can reach a point that none of its emitters reaches; a sample that walks there
// finds no light, which costs variance, not bias); Pmf(p, n, i) is exactly the probability Sample returns
// for i (the same float operations along the same root-to-leaf path); an emitter gets
// probability 0 only where its emission cone faces away from the point by more than a
// margin, so sampling never misses light it could deliver.
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

#include "math.h"

namespace tessera {

// What one emitter (or a node: the union of its emitters) can deliver.
struct LightBounds {
    static constexpr float kInf = std::numeric_limits<float>::infinity();
    Vec3 lo = Vec3(kInf, kInf, kInf), hi = Vec3(-kInf, -kInf, -kInf);
    float phi = 0.f;          // emitted power (selection weight)
    Vec3 w = Vec3(0.f, 0.f, 1.f);  // axis of the normals' cone
    float cos_theta_o = 1.f;  // the cone's half-angle: every emitting normal is within it of w
    bool two_sided = false;   // emits on both sides of each normal

    // An upper bound, up to a common factor, on what these emitters can deliver at p to a
    // surface with normal n (n = 0: any orientation). 0 only if no emitter can reach p.
    float Importance(Vec3 p, Vec3 n) const;
    static LightBounds Union(const LightBounds& a, const LightBounds& b);
    // One emitting triangle: its box, its normal Cross(p1 - p0, p2 - p0) as the cone's axis
    // (half-angle 0). phi 0 (nothing to choose) when it is degenerate.
    static LightBounds Triangle(const Vec3 p[3], float phi, bool two_sided);
};

class BVHLightSampler {
public:
    BVHLightSampler() = default;
    // bounds[i] describes emitter ids[i]; `num_emitters` sizes the emitter-to-leaf table.
    BVHLightSampler(const std::vector<LightBounds>& bounds, const std::vector<uint32_t>& ids, size_t num_emitters);

    bool empty() const { return nodes_.empty(); }
    // u in [0, 1). Returns false (pmf 0) when no emitter can light p.
    bool Sample(float u, Vec3 p, Vec3 n, uint32_t* emitter, float* pmf) const;
    // The probability that Sample(., p, n) returns `emitter`; 0 for emitters not in the tree.
    float Pmf(Vec3 p, Vec3 n, uint32_t emitter) const;
    size_t num_nodes() const { return nodes_.size(); }

private:
    struct Node {
        LightBounds bounds;
        uint32_t second_child_or_emitter = 0;  // interior: right child (left is this + 1); leaf: emitter id
        bool leaf = false;
    };
    uint32_t Build(std::vector<uint32_t>& order, size_t begin, size_t end, const std::vector<LightBounds>& bounds,
                   const std::vector<uint32_t>& ids, uint64_t trail, int depth);
    // Probability of taking the left child of interior node `i` at (p, n); < 0 when neither
    // child can light p.
    float LeftProbability(uint32_t i, Vec3 p, Vec3 n) const;

    std::vector<Node> nodes_;
    std::vector<uint64_t> trail_;  // per emitter: bit d = 1 if the path to its leaf goes right at depth d
    std::vector<uint8_t> depth_;   // per emitter: its leaf's depth; 255 = not in the tree
};

}  // namespace tessera
