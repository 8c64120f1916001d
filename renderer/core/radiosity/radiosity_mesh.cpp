#include "radiosity_mesh.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>

#include "sampling.h"

namespace tessera {

namespace {


// The reflectance radiosity gives a surface: the bihemispherical reflectance of its BSDF's
// non-delta lobes, rho = (1/pi) Int Int f cos cos dwi dwo, i.e. pi times the mean of f over
// two cosine-distributed directions (midpoints of 16 x 16 strata each). A Lambertian gets
// its albedo back; a rough UsdPreviewSurface keeps the energy of its specular lobe (spread
// as if diffuse); delta lobes (mirrors, clear glass) reflect nothing here. Textures are
// not evaluated: the material's constant inputs are used.
Color Reflectance(const Scene& scene, const SurfaceHit& hit) {
    const BSDF bsdf = scene.BSDFAt(hit, TransportMode::Radiance);
    if (!bsdf.IsNonSpecular()) return Color(0.f);
    constexpr int kStrata = 16;
    std::vector<Vec3> dirs;
    dirs.reserve(kStrata * kStrata);
    for (int a = 0; a < kStrata; ++a)
        for (int b = 0; b < kStrata; ++b)
            dirs.push_back(SampleCosineHemisphere(Vec2((a + 0.5f) / kStrata, (b + 0.5f) / kStrata)));
    double sum[3] = {0.0, 0.0, 0.0};
    for (const Vec3& wo : dirs)
        for (const Vec3& wi : dirs) {
            const Color f = bsdf.f(wo, wi);
            sum[0] += f.x, sum[1] += f.y, sum[2] += f.z;
        }
    const double scale = kPi / double(dirs.size() * dirs.size());
    auto clamp = [](double v) { return float(std::clamp(v, 0.0, 1.0)); };
    return Color(clamp(sum[0] * scale), clamp(sum[1] * scale), clamp(sum[2] * scale));
}

}  // namespace

// Elements per edge of a source triangle: its longest edge over the target size (1 to
// 4096). A degenerate triangle (no area: a line or a point) exchanges no light, so it
// gets one element however long it is.
uint32_t RadiosityMesh::CellsPerEdge(const Vec3 p[3], float target_size) {
    const float area2 = Length(Cross(p[1] - p[0], p[2] - p[0]));
    if (!(area2 > 0.f) || !std::isfinite(area2)) return 1;
    const float longest = std::max({Length(p[1] - p[0]), Length(p[2] - p[0]), Length(p[2] - p[1])});
    return uint32_t(std::clamp(std::ceil(double(longest) / target_size), 1.0, 4096.0));
}

RadiosityMesh::RadiosityMesh(const Scene& scene, float target_size, const std::vector<uint8_t>& leaf_depth) {
    if (!(target_size > 0.f) || !std::isfinite(target_size))
        throw std::invalid_argument("radiosity element_size must be a finite number > 0");
    // Welding tolerance: far below any element, far above rounding in the corners.
    quantum_ = RadiosityLengthScale(scene);
    // Count first: a tiny element_size must be refused before it allocates (a worker
    // must not run out of memory on a bad setting).
    double cells = 0.0;
    scene.ForEachTriangle([&](uint32_t, uint32_t, uint32_t, const Vec3* p, float) {
        const double n = CellsPerEdge(p, target_size);
        cells += n * n;
    });
    const double count = leaf_depth.empty() ? cells : double(leaf_depth.size());
    if (count > double(kMaxElements))
        throw std::invalid_argument("radiosity element_size " + std::to_string(target_size) + " would cut the scene into " +
                                    std::to_string(uint64_t(count)) + " elements (at most " +
                                    std::to_string(kMaxElements) + "); make it larger");
    num_cells_ = size_t(cells);
    if (!leaf_depth.empty()) {
        // The leaves of each cell tile it in preorder: a leaf of depth d covers 4^(D - d)
        // of its cell's 4^D finest cells (D = kMaxDepth), starting at a multiple of that.
        constexpr uint32_t kFinest = 1u << (2 * kMaxDepth);
        leaf_depth_ = leaf_depth;
        leaf_offset_.resize(leaf_depth.size());
        cell_first_.assign(1, 0);
        uint32_t offset = 0;
        for (size_t e = 0; e < leaf_depth.size(); ++e) {
            const uint8_t d = leaf_depth[e];
            const uint32_t size = d <= kMaxDepth ? 1u << (2 * (kMaxDepth - d)) : 0u;
            if (size == 0 || offset % size != 0 || cell_first_.size() > num_cells_)
                throw std::invalid_argument("radiosity refinement does not tile the mesh's cells");
            leaf_offset_[e] = uint8_t(offset);
            offset += size;
            if (offset == kFinest) cell_first_.push_back(uint32_t(e + 1)), offset = 0;
        }
        if (offset != 0 || cell_first_.size() != num_cells_ + 1)
            throw std::invalid_argument("radiosity refinement does not tile the mesh's cells");
    }
    elements_.resize(size_t(count));
    world_.resize(scene.num_triangles());
    scene.ForEachTriangle([&](uint32_t mesh, uint32_t prim, uint32_t instance, const Vec3* p, float sign) {
        AddSource(scene, mesh, prim, instance, p, sign, target_size);
    });
    if (refined()) FindHangingVertices();
    vertex_index_.clear();
    reflectance_.clear();
}

namespace {

auto VertexKeyOf(Vec3 p, Vec3 n, float quantum) {
    auto q = [&](float x) { return int64_t(std::llround(x / quantum)); };
    auto qn = [](float x) { return int64_t(std::lround((x + 1.f) * 3.f)); };
    return std::array<int64_t, 4>{q(p.x), q(p.y), q(p.z), qn(n.x) | (qn(n.y) << 3) | (qn(n.z) << 6)};
}

// The cell of an n-per-edge grid holding grid coordinates (x, y) (barycentrics times n)
// and the weights of its three corners, as the cells' corners are listed: an upward cell
// (i, j) has (i, j), (i+1, j), (i, j+1); a downward one (i+1, j), (i+1, j+1), (i, j+1).
uint32_t GridCell(uint32_t n, float x, float y, float w[3]) {
    const uint32_t i = uint32_t(std::clamp(std::floor(x), 0.f, float(n - 1)));
    const uint32_t j = uint32_t(std::clamp(std::floor(y), 0.f, float(n - 1 - i)));
    const float fx = x - float(i), fy = y - float(j);
    if (fx + fy > 1.f && i + j + 1 < n) {
        w[0] = 1.f - fy;
        w[1] = fx + fy - 1.f;
        w[2] = 1.f - fx;
        return DownCell(n, i, j);
    }
    w[1] = std::clamp(fx, 0.f, 1.f);
    w[2] = std::clamp(fy, 0.f, 1.f - w[1]);
    w[0] = 1.f - w[1] - w[2];
    return UpCell(n, i, j);
}

// The corners of cell `index` of an n-per-edge grid, in grid coordinates.
void CellCorners(uint32_t n, uint32_t index, float c[3][2]) {
    const uint32_t up = n * (n + 1) / 2;
    const bool down = index >= up;
    uint32_t k = down ? index - up : index, row = down ? n - 1 : n, i = 0;
    while (k >= row) k -= row, --row, ++i;
    const float fi = float(i), fj = float(k);
    if (!down) {
        c[0][0] = fi, c[0][1] = fj, c[1][0] = fi + 1, c[1][1] = fj, c[2][0] = fi, c[2][1] = fj + 1;
    } else {
        c[0][0] = fi + 1, c[0][1] = fj, c[1][0] = fi + 1, c[1][1] = fj + 1, c[2][0] = fi, c[2][1] = fj + 1;
    }
}

// Child k of a triangle's midpoint subdivision, corners as the parent's are listed: the
// three corner triangles, then the inverted middle one (all wound as the parent).
void ChildCorners(const float c[3][2], uint32_t k, float out[3][2]) {
    float m[3][2];  // midpoints of edges 01, 12, 20
    for (int e = 0; e < 3; ++e)
        for (int a = 0; a < 2; ++a) m[e][a] = 0.5f * (c[e][a] + c[(e + 1) % 3][a]);
    const float* pick[4][3] = {{c[0], m[0], m[2]}, {m[0], c[1], m[1]}, {m[2], m[1], c[2]}, {m[1], m[2], m[0]}};
    for (int v = 0; v < 3; ++v) out[v][0] = pick[k][v][0], out[v][1] = pick[k][v][1];
}

// The child of a triangle holding the point with weights (1 - w1 - w2, w1, w2), and the
// point's weights (w1, w2) in it.
uint32_t ChildHolding(float* w1, float* w2) {
    const float w0 = 1.f - *w1 - *w2;
    if (w0 >= 0.5f) return *w1 *= 2.f, *w2 *= 2.f, 0u;
    if (*w1 >= 0.5f) return *w1 = 2.f * *w1 - 1.f, *w2 *= 2.f, 1u;
    if (*w2 >= 0.5f) return *w1 *= 2.f, *w2 = 2.f * *w2 - 1.f, 2u;
    return *w1 = 1.f - 2.f * *w1, *w2 = 1.f - 2.f * *w2, 3u;
}

}  // namespace

uint32_t RadiosityMesh::Vertex(Vec3 p, Vec3 n) {
    // Elements meet at a vertex only on the same side of the same plane-ish surface: a
    // corner of a box keeps one vertex per wall, so walls do not bleed into each other.
    const auto k = VertexKeyOf(p, n, quantum_);
    auto [it, inserted] = vertex_index_.try_emplace(VertexKey{k[0], k[1], k[2], k[3]}, uint32_t(num_vertices_));
    if (inserted) ++num_vertices_;
    return it->second;
}

int64_t RadiosityMesh::FindVertex(Vec3 p, Vec3 n) const {
    const auto k = VertexKeyOf(p, n, quantum_);
    auto it = vertex_index_.find(VertexKey{k[0], k[1], k[2], k[3]});
    return it == vertex_index_.end() ? -1 : int64_t(it->second);
}

void RadiosityMesh::AddSource(const Scene& scene, uint32_t mesh, uint32_t prim, uint32_t instance, const Vec3 p[3],
                              float sign, float target_size) {
    const Vec3 e1 = p[1] - p[0], e2 = p[2] - p[0];
    const uint32_t n = CellsPerEdge(p, target_size);
    const Source src{uint32_t(source_list_.empty() ? 0 : source_list_.back().first + source_list_.back().n *
                                                                                       source_list_.back().n),
                     n};
    if (instance == kNoInstance) world_[prim] = src;
    else instanced_[(uint64_t(instance) << 32) | prim] = src;
    ++num_sources_;
    source_list_.push_back({{p[0], p[1], p[2]}, src.first, n});

    const Vec3 cross = Cross(e1, e2) * sign;
    const float len = Length(cross);
    const Vec3 ng = len > 0.f ? cross / len : Vec3(0.f, 0.f, 1.f);

    SurfaceHit hit;
    hit.geom_id = Scene::kTriangleGeometry;
    hit.mesh = mesh;
    hit.prim_id = prim;
    hit.instance = instance;
    hit.ng = ng;
    hit.ns = ng;
    const Material* material = &scene.MaterialAt(hit);
    auto cached = reflectance_.find(material);
    if (cached == reflectance_.end()) cached = reflectance_.emplace(material, Reflectance(scene, hit)).first;
    const Color rho = cached->second;
    const int32_t emitter = scene.EmitterAt(hit);

    // Grid point (i, j) = p0 + e1 i/n + e2 j/n; its vertex is welded with its neighbours'.
    std::vector<uint32_t> grid((n + 1) * (n + 2) / 2);
    auto gi = [&](uint32_t i, uint32_t j) { return i * (n + 1) - i * (i - 1) / 2 + j; };
    auto point = [&](float u, float v) { return p[0] + e1 * (u / float(n)) + e2 * (v / float(n)); };
    for (uint32_t i = 0; i <= n; ++i)
        for (uint32_t j = 0; i + j <= n; ++j) grid[gi(i, j)] = Vertex(point(float(i), float(j)), ng);

    // One element: corners in grid coordinates and their display vertices.
    auto make = [&](size_t index, const float c[3][2], const uint32_t v[3]) {
        RadiosityElement& el = elements_[index];
        float b1 = 0.f, b2 = 0.f;
        for (int k = 0; k < 3; ++k) {
            el.p[k] = point(c[k][0], c[k][1]);
            el.vertex[k] = v[k];
            b1 += c[k][0] / (3.f * n);
            b2 += c[k][1] / (3.f * n);
        }
        el.n = ng;
        el.center = (el.p[0] + el.p[1] + el.p[2]) / 3.f;
        el.area = 0.5f * Length(Cross(el.p[1] - el.p[0], el.p[2] - el.p[0]));
        el.rho = rho;
        el.emitter = emitter;
        if (emitter != Scene::kNoEmitter) {
            hit.b1 = b1;
            hit.b2 = b2;
            el.emission[0] = scene.Emitted(emitter, hit, ng) * kPi;
            el.emission[1] = scene.Emitted(emitter, hit, -ng) * kPi;
        }
    };
    for (uint32_t cell = 0; cell < n * n; ++cell) {
        float c[3][2];
        CellCorners(n, cell, c);
        uint32_t v[3];
        for (int k = 0; k < 3; ++k) v[k] = grid[gi(uint32_t(c[k][0]), uint32_t(c[k][1]))];
        const size_t global = size_t(src.first) + cell;
        if (!refined()) {
            make(global, c, v);
            continue;
        }
        for (size_t e = CellFirst(global); e < CellFirst(global + 1); ++e) {
            float g[3][2] = {{c[0][0], c[0][1]}, {c[1][0], c[1][1]}, {c[2][0], c[2][1]}};
            for (uint32_t level = 0; level < leaf_depth_[e]; ++level) {
                float child[3][2];
                ChildCorners(g, (leaf_offset_[e] >> (2 * (kMaxDepth - 1 - level))) & 3u, child);
                std::memcpy(g, child, sizeof(g));
            }
            uint32_t sv[3];
            for (int k = 0; k < 3; ++k) sv[k] = Vertex(point(g[k][0], g[k][1]), ng);
            make(e, g, sv);
        }
    }
}

void RadiosityMesh::FindHangingVertices() {
    // Probe every leaf edge at the finest spacing a neighbour could have; a vertex found
    // there belongs to a finer neighbour and hangs on this edge.
    std::vector<std::pair<uint8_t, HangingVertex>> found;
    for (size_t e = 0; e < elements_.size(); ++e) {
        const uint8_t d = leaf_depth_[e];
        if (d == kMaxDepth) continue;
        const uint32_t parts = 1u << (kMaxDepth - d);
        const RadiosityElement& el = elements_[e];
        for (int k = 0; k < 3; ++k) {
            const Vec3 P = el.p[k], Q = el.p[(k + 1) % 3];
            const uint32_t a = el.vertex[k], b = el.vertex[(k + 1) % 3];
            for (uint32_t i = 1; i < parts; ++i) {
                const float t = float(i) / float(parts);
                const int64_t v = FindVertex(P + (Q - P) * t, el.n);
                if (v >= 0 && uint32_t(v) != a && uint32_t(v) != b) found.push_back({d, {uint32_t(v), a, b, t}});
            }
        }
    }
    std::stable_sort(found.begin(), found.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
    hanging_.reserve(found.size());
    for (const auto& f : found) hanging_.push_back(f.second);
}

int32_t RadiosityMesh::Locate(const SurfaceHit& hit, float w[3]) const {
    if (hit.geom_id != Scene::kTriangleGeometry) return -1;
    const Source* src = nullptr;
    if (hit.instance == kNoInstance) {
        if (hit.prim_id >= world_.size()) return -1;
        src = &world_[hit.prim_id];
    } else {
        auto it = instanced_.find((uint64_t(hit.instance) << 32) | hit.prim_id);
        if (it == instanced_.end()) return -1;
        src = &it->second;
    }
    const uint32_t n = src->n;
    const uint32_t cell = GridCell(n, std::clamp(hit.b1, 0.f, 1.f) * n, std::clamp(hit.b2, 0.f, 1.f) * n, w);
    const size_t global = size_t(src->first) + cell;
    if (!refined()) return int32_t(global);
    const size_t first = CellFirst(global), last = CellFirst(global + 1);
    if (last - first == 1) return int32_t(first);
    // The point's path to the finest level, as a preorder offset; its leaf is the last
    // one starting at or before it.
    float w1 = w[1], w2 = w[2];
    uint32_t path = 0;
    for (uint32_t level = 0; level < kMaxDepth; ++level) path = path * 4 + ChildHolding(&w1, &w2);
    const auto begin = leaf_offset_.begin() + first, end = leaf_offset_.begin() + last;
    const size_t e = size_t(std::upper_bound(begin, end, uint8_t(path)) - leaf_offset_.begin()) - 1;
    w1 = w[1], w2 = w[2];
    for (uint32_t level = 0; level < leaf_depth_[e]; ++level) ChildHolding(&w1, &w2);
    w[1] = std::clamp(w1, 0.f, 1.f);
    w[2] = std::clamp(w2, 0.f, 1.f - w[1]);
    w[0] = 1.f - w[1] - w[2];
    return int32_t(e);
}

std::vector<Color> RadiosityMesh::VertexAverage(const std::vector<Color>& element_values) const {
    std::vector<Color> sum(2 * num_vertices_, Color(0.f));
    std::vector<float> weight(2 * num_vertices_, 0.f);
    for (size_t e = 0; e < elements_.size(); ++e) {
        const RadiosityElement& el = elements_[e];
        for (int side = 0; side < 2; ++side)
            for (int k = 0; k < 3; ++k) {
                sum[2 * el.vertex[k] + side] += element_values[2 * e + side] * el.area;
                weight[2 * el.vertex[k] + side] += el.area;
            }
    }
    for (size_t v = 0; v < sum.size(); ++v)
        if (weight[v] > 0.f) sum[v] = sum[v] / weight[v];
    SettleHanging(&sum);
    return sum;
}

void RadiosityMesh::SettleHanging(std::vector<Color>* vertex_values) const {
    std::vector<Color>& v = *vertex_values;
    // Coarse edges first: a hanging vertex's edge ends are settled before it.
    for (const HangingVertex& h : hanging_)
        for (int side = 0; side < 2; ++side)
            v[2 * h.v + side] = v[2 * h.a + side] * (1.f - h.t) + v[2 * h.b + side] * h.t;
}

}  // namespace tessera
