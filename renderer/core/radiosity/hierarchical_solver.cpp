#include "hierarchical_solver.h"

#include <stdexcept>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <cmath>

#include "form_factor.h"

namespace tessera {

namespace {

struct Node {
    Vec3 p[3];
    Vec3 c, n;
    float area = 0.f;
    int32_t child = -1;  // first of four consecutive children, or -1 for a leaf
    int depth = 0, max_depth = 0;
    Color rho, E[2], Dn[2];  // Dn: reflected light of unmeshed lights (leaves)
    Color gathered[2], B[2], direct[2];
};

struct Link {
    uint32_t from;
    float F;      // F from the receiver (on side `side`) to `from`, visibility included
    uint8_t side, from_side;
};

class Hierarchy {
public:
    Hierarchy(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& s)
        : scene_(scene), settings_(s), eps_(RadiosityLengthScale(scene)) {
        const auto& el = mesh.elements();
        for (const auto& src : mesh.sources()) {
            Node root;
            for (int k = 0; k < 3; ++k) root.p[k] = src.p[k];
            const RadiosityElement& first = el[src.first];
            root.n = first.n;
            root.rho = first.rho;
            root.E[0] = first.emission[0];
            root.E[1] = first.emission[1];
            root.max_depth = int(std::ceil(std::log2(double(src.n)) - 1e-9));
            Finish(&root);
            roots_.push_back(uint32_t(nodes_.size()));
            nodes_.push_back(root);
        }
        links_.resize(nodes_.size());
    }

    void Finish(Node* n) {
        n->c = (n->p[0] + n->p[1] + n->p[2]) / 3.f;
        n->area = 0.5f * Length(Cross(n->p[1] - n->p[0], n->p[2] - n->p[0]));
    }

    void Subdivide(uint32_t i) {
        if (nodes_[i].child >= 0) return;
        const Node parent = nodes_[i];
        const Vec3 m01 = (parent.p[0] + parent.p[1]) * 0.5f, m12 = (parent.p[1] + parent.p[2]) * 0.5f,
                   m20 = (parent.p[2] + parent.p[0]) * 0.5f;
        const Vec3 corners[4][3] = {{parent.p[0], m01, m20}, {m01, parent.p[1], m12}, {m20, m12, parent.p[2]},
                                    {m12, m20, m01}};
        nodes_[i].child = int32_t(nodes_.size());
        for (const auto& cs : corners) {
            Node c;
            for (int k = 0; k < 3; ++k) c.p[k] = cs[k];
            c.n = parent.n;
            c.rho = parent.rho;
            c.E[0] = parent.E[0];
            c.E[1] = parent.E[1];
            c.depth = parent.depth + 1;
            c.max_depth = parent.max_depth;
            Finish(&c);
            nodes_.push_back(c);
            links_.emplace_back();
        }
    }

    // Radiosity q sends toward p, as the oracle sees it.
    float SourceEstimate(uint32_t q, int side) const {
        return Luminance(nodes_[q].E[side] + nodes_[q].B[side]);
    }

    // Where triangle t lies against the plane through c with normal n: kFront, kBack,
    // kInPlane (within eps), or kStraddles (vertices beyond eps on both sides).
    enum PlaneSide { kFront, kBack, kInPlane, kStraddles };
    PlaneSide SideOf(const Vec3 t[3], Vec3 c, Vec3 n) const {
        float lo = 0.f, hi = 0.f;
        for (int k = 0; k < 3; ++k) {
            const float h = Dot(t[k] - c, n);
            lo = std::min(lo, h);
            hi = std::max(hi, h);
        }
        if (hi > eps_ && lo < -eps_) return kStraddles;
        if (hi > eps_) return kFront;
        if (lo < -eps_) return kBack;
        return kInPlane;
    }

    // Splits the source q (or the receiver p) into its 4 children and links each to the other.
    void SplitAndRefine(uint32_t p, uint32_t q, bool split_source, float threshold) {
        const uint32_t split = split_source ? q : p;
        Subdivide(split);
        const int32_t c = nodes_[split].child;
        for (int k = 0; k < 4; ++k)
            split_source ? Refine(p, uint32_t(c + k), threshold) : Refine(uint32_t(c + k), q, threshold);
    }

    // Links p <- q, refined until the BF oracle is met or both are elements.
    void Refine(uint32_t p, uint32_t q, float threshold) {
        const Node& np = nodes_[p];
        const Node& nq = nodes_[q];
        if (IsBlack(np.rho)) return;
        const bool can_p = np.depth < np.max_depth, can_q = nq.depth < nq.max_depth;
        // Each end must lie on one side of the other's plane, or one side of it would
        // exchange light with the wrong side of the other (a wall beside a block's face:
        // the part in front of the face sees it, the part behind sees its inside). A
        // straddling node is split; only elements that still straddle fall back to the
        // side of the centres.
        const PlaneSide q_vs_p = SideOf(nq.p, np.c, np.n), p_vs_q = SideOf(np.p, nq.c, nq.n);
        if (q_vs_p == kInPlane || p_vs_q == kInPlane) return;
        if (q_vs_p == kStraddles && can_q) return SplitAndRefine(p, q, /*split_source=*/true, threshold);
        if (p_vs_q == kStraddles && can_p) return SplitAndRefine(p, q, /*split_source=*/false, threshold);
        const Vec3 d = nq.c - np.c;
        const float hp = q_vs_p == kStraddles ? Dot(d, np.n) : (q_vs_p == kFront ? 1.f : -1.f);
        const float hq = p_vs_q == kStraddles ? -Dot(d, nq.n) : (p_vs_q == kFront ? 1.f : -1.f);
        if (hp == 0.f || hq == 0.f) return;
        const uint8_t sp = hp > 0.f ? 0 : 1, sq = hq > 0.f ? 0 : 1;
        const Vec3 normal_p = sp ? -np.n : np.n, normal_q = sq ? -nq.n : nq.n;
        // F and visibility averaged over 4 points of the receiver, each with a shadow ray to
        // its counterpart on the source (the progressive solver's element estimator): a
        // coarse link neither takes its centre's factor for the whole node nor its centre's
        // shadow.
        float Fk[4];
        const float F = ReceiverMeanFormFactor(np.p, normal_p, nq.p, Fk);
        if (!(F > 0.f)) return;
        const float oracle = Luminance(np.rho) * F * SourceEstimate(q, sq);
        bool refine = oracle > threshold && (can_p || can_q);
        float FV = 0.f;
        if (!refine) {
            int visible = 0;
            FV = VisibleReceiverMeanFormFactor(scene_, np.p, normal_p, nq.p, normal_q, eps_, Fk, &visible);
            // A shadow boundary may cross the link (some rays blocked), or a blocker may
            // hide the 4 rays' ends but not all of the two nodes (all blocked): refine it
            // while it carries a tenth of what the oracle allows. Dropping a fully blocked
            // coarse link outright loses the light that passes beside the blocker.
            refine = visible < 4 && (can_p || can_q) && oracle > 0.1f * threshold;
        }
        if (refine) {
            // Split the larger (the one whose size limits the estimate's accuracy most).
            return SplitAndRefine(p, q, can_q && (!can_p || nq.area > np.area), threshold);
        }
        if (FV > 0.f) links_[p].push_back({q, FV, sp, sq});
    }

    void LinkAll(float threshold) {
        for (auto& l : links_) l.clear();
        for (uint32_t a : roots_)
            for (uint32_t b : roots_)
                if (a != b) Refine(a, b, threshold);
        links_.resize(nodes_.size());
    }

    // Pushes gathered radiosity down to the leaves and pulls area-weighted means up.
    void PushPull(uint32_t i, Color down0, Color down1, bool direct_only) {
        Node& n = nodes_[i];
        const Color d0 = down0 + n.gathered[0], d1 = down1 + n.gathered[1];
        if (n.child < 0) {
            if (direct_only) {
                n.direct[0] = d0 + n.Dn[0];
                n.direct[1] = d1 + n.Dn[1];
            } else {
                n.B[0] = d0 + n.Dn[0];
                n.B[1] = d1 + n.Dn[1];
            }
            return;
        }
        Color sum0(0.f), sum1(0.f);
        for (int k = 0; k < 4; ++k) {
            const uint32_t c = uint32_t(n.child + k);
            PushPull(c, d0, d1, direct_only);
            const Node& cn = nodes_[c];
            const float w = n.area > 0.f ? cn.area / n.area : 0.25f;
            sum0 += (direct_only ? cn.direct[0] : cn.B[0]) * w;
            sum1 += (direct_only ? cn.direct[1] : cn.B[1]) * w;
        }
        Node& m = nodes_[i];
        if (direct_only) {
            m.direct[0] = sum0;
            m.direct[1] = sum1;
        } else {
            m.B[0] = sum0;
            m.B[1] = sum1;
        }
    }

    // One Jacobi sweep: every node gathers over its links from the sources' reflected B
    // plus emission (or emission alone, for the direct part).
    void Gather(tbb::task_arena& arena, bool emission_only) {
        arena.execute([&] {
            tbb::parallel_for(tbb::blocked_range<size_t>(0, nodes_.size(), 256), [&](const auto& r) {
                for (size_t i = r.begin(); i != r.end(); ++i) {
                    Color g[2] = {Color(0.f), Color(0.f)};
                    for (const auto& l : links_[i]) {
                        const Node& q = nodes_[l.from];
                        const Color src = emission_only ? q.E[l.from_side] : q.E[l.from_side] + q.B[l.from_side];
                        g[l.side] += src * l.F;
                    }
                    nodes_[i].gathered[0] = nodes_[i].rho * g[0];
                    nodes_[i].gathered[1] = nodes_[i].rho * g[1];
                }
            });
        });
    }

    // The leaf under point x of root r.
    uint32_t Leaf(uint32_t r, Vec3 x) const {
        uint32_t i = r;
        while (nodes_[i].child >= 0) {
            uint32_t best = uint32_t(nodes_[i].child);
            float best_score = -1e30f;
            for (int k = 0; k < 4; ++k) {
                const Node& c = nodes_[uint32_t(nodes_[i].child + k)];
                // The smallest barycentric of x in the child: >= 0 inside.
                const Vec3 e1 = c.p[1] - c.p[0], e2 = c.p[2] - c.p[0], v = x - c.p[0];
                const float d11 = Dot(e1, e1), d12 = Dot(e1, e2), d22 = Dot(e2, e2), v1 = Dot(v, e1), v2 = Dot(v, e2);
                const float den = d11 * d22 - d12 * d12;
                const float b1 = den != 0.f ? (d22 * v1 - d12 * v2) / den : 0.f;
                const float b2 = den != 0.f ? (d11 * v2 - d12 * v1) / den : 0.f;
                const float score = std::min({1.f - b1 - b2, b1, b2});
                if (score > best_score) best_score = score, best = uint32_t(nodes_[i].child + k);
            }
            i = best;
        }
        return i;
    }

    const Scene& scene_;
    RadiositySettings settings_;
    float eps_;
    std::vector<Node> nodes_;
    std::vector<std::vector<Link>> links_;
    std::vector<uint32_t> roots_;
};

}  // namespace

RadiositySolution SolveHierarchical(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings) {
    if (mesh.refined())
        throw std::invalid_argument("the hierarchical radiosity solver refines its own links: refine_levels needs "
                                    "solver 0 (progressive) or 2 (stochastic)");
    const auto& el = mesh.elements();
    RadiositySolution sol;
    sol.radiosity.assign(2 * el.size(), Color(0.f));
    sol.direct.assign(2 * el.size(), Color(0.f));
    sol.unshot.assign(2 * el.size(), Color(0.f));
    sol.converged = true;
    if (el.empty()) return sol;
    tbb::task_arena arena(settings.threads > 0 ? settings.threads : tbb::this_task_arena::max_concurrency());
    Hierarchy h(scene, mesh, settings);
    float brightest = 0.f;
    for (const RadiosityElement& e : el) brightest = std::max({brightest, Luminance(e.emission[0]), Luminance(e.emission[1])});
    const std::vector<uint32_t> lights = UnmeshedLights(scene, mesh);

    auto solve = [&] {
        // Unmeshed lights at the leaves (their reflected light is a source like emission).
        arena.execute([&] {
            tbb::parallel_for(tbb::blocked_range<size_t>(0, h.nodes_.size(), 64), [&](const auto& r) {
                const ShutterTimeScope instant(settings.shutter_time);
                for (size_t i = r.begin(); i != r.end(); ++i) {
                    Node& n = h.nodes_[i];
                    for (int s = 0; s < 2; ++s)
                        n.Dn[s] = lights.empty() || n.child >= 0 || IsBlack(n.rho)
                                      ? Color(0.f)
                                      : n.rho * GatherIrradiance(scene, n.c, s ? -n.n : n.n, lights,
                                                                 settings.light_samples, settings.seed, 2 * i + s,
                                                                 RadiosityLengthScale(scene));
                }
            });
        });
        h.Gather(arena, true);
        for (uint32_t r : h.roots_) h.PushPull(r, Color(0.f), Color(0.f), true);
        for (auto& n : h.nodes_) n.B[0] = n.direct[0], n.B[1] = n.direct[1];
        sol.residual.clear();
        for (int iter = 0; iter < 200; ++iter) {
            h.Gather(arena, false);
            double change = 0.0, total = 0.0;
            std::vector<Color> before(2 * h.roots_.size());
            for (size_t k = 0; k < h.roots_.size(); ++k)
                before[2 * k] = h.nodes_[h.roots_[k]].B[0], before[2 * k + 1] = h.nodes_[h.roots_[k]].B[1];
            for (uint32_t r : h.roots_) h.PushPull(r, Color(0.f), Color(0.f), false);
            for (size_t k = 0; k < h.roots_.size(); ++k) {
                const Node& n = h.nodes_[h.roots_[k]];
                for (int s = 0; s < 2; ++s) {
                    change += std::abs(double(Luminance(n.B[s] - before[2 * k + s]))) * n.area;
                    total += double(Luminance(n.B[s] + n.E[s])) * n.area;
                }
            }
            sol.residual.push_back(change);
            sol.entered_power = total;
            // The links' accuracy is the oracle's business; the iteration itself runs to
            // a fixed 1e-5 of the power, so a coarse oracle does not stop it early.
            if (change <= 1e-5 * total) break;
        }
    };

    // BF refinement: link by emission alone, solve, relink with the solved B, twice.
    const float threshold = settings.tolerance * std::max(brightest, 1e-30f);
    for (int round = 0; round < 3; ++round) {
        h.LinkAll(threshold);
        solve();
    }
    sol.converged = !sol.residual.empty() && sol.residual.back() <= 1e-5 * sol.entered_power;
    for (const auto& l : h.links_) sol.links += l.size();
    sol.nodes = h.nodes_.size();
    sol.shots = uint32_t(std::min<size_t>(sol.links, 0xFFFFFFFFu));

    // Each uniform element takes the hierarchy's mean over its area: the leaves are 2^d per
    // source edge, the elements n (not a power of two), so one element overlaps several
    // leaves; the mean is taken at the centroids of its m^2 similar sub-triangles (equal
    // areas), m = 4. Taking only the leaf under the element's centre aliases the leaves'
    // pattern onto the elements.
    const std::vector<std::array<float, 2>> sub = SubTriangleCentroids(4);
    const auto& sources = mesh.sources();
    for (size_t s = 0; s < sources.size(); ++s) {
        const uint32_t root = h.roots_[s];
        for (uint32_t k = 0; k < sources[s].n * sources[s].n; ++k) {
            const size_t e = sources[s].first + k;
            const RadiosityElement& x = el[e];
            Color B[2] = {Color(0.f), Color(0.f)}, D[2] = {Color(0.f), Color(0.f)};
            for (const auto& b : sub) {
                const Vec3 at = x.p[0] + (x.p[1] - x.p[0]) * b[0] + (x.p[2] - x.p[0]) * b[1];
                const Node& leaf = h.nodes_[h.Leaf(root, at)];
                for (int side = 0; side < 2; ++side) B[side] += leaf.B[side], D[side] += leaf.direct[side];
            }
            const float w = 1.f / float(sub.size());
            for (int side = 0; side < 2; ++side) {
                sol.radiosity[2 * e + side] = x.emission[side] + B[side] * w;
                sol.direct[2 * e + side] = D[side] * w;
            }
        }
    }
    return sol;
}

}  // namespace tessera
