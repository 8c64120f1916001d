#include "radiosity_mesh.h"

#include <algorithm>
#include <cmath>
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

RadiosityMesh::RadiosityMesh(const Scene& scene, float target_size) {
    if (!(target_size > 0.f) || !std::isfinite(target_size))
        throw std::invalid_argument("radiosity element_size must be a finite number > 0");
    // Welding tolerance: far below any element, far above rounding in the corners.
    quantum_ = 1e-4f * std::max(1.f, scene.scene_radius());
    // Count first: a tiny element_size must be refused before it allocates (a worker
    // must not run out of memory on a bad setting).
    double count = 0.0;
    scene.ForEachTriangle([&](uint32_t, uint32_t, uint32_t, const Vec3* p, float) {
        const double n = CellsPerEdge(p, target_size);
        count += n * n;
    });
    if (count > double(kMaxElements))
        throw std::invalid_argument("radiosity element_size " + std::to_string(target_size) + " would cut the scene into " +
                                    std::to_string(uint64_t(count)) + " elements (at most " +
                                    std::to_string(kMaxElements) + "); make it larger");
    world_.resize(scene.num_triangles());
    scene.ForEachTriangle([&](uint32_t mesh, uint32_t prim, uint32_t instance, const Vec3* p, float sign) {
        AddSource(scene, mesh, prim, instance, p, sign, target_size);
    });
    vertex_index_.clear();
    reflectance_.clear();
}

uint32_t RadiosityMesh::Vertex(Vec3 p, Vec3 n) {
    // Elements meet at a vertex only on the same side of the same plane-ish surface: a
    // corner of a box keeps one vertex per wall, so walls do not bleed into each other.
    auto q = [&](float x) { return int64_t(std::llround(x / quantum_)); };
    auto qn = [](float x) { return int64_t(std::lround((x + 1.f) * 3.f)); };
    const VertexKey key{q(p.x), q(p.y), q(p.z), qn(n.x) | (qn(n.y) << 3) | (qn(n.z) << 6)};
    auto [it, inserted] = vertex_index_.try_emplace(key, uint32_t(num_vertices_));
    if (inserted) ++num_vertices_;
    return it->second;
}

void RadiosityMesh::AddSource(const Scene& scene, uint32_t mesh, uint32_t prim, uint32_t instance, const Vec3 p[3],
                              float sign, float target_size) {
    const Vec3 e1 = p[1] - p[0], e2 = p[2] - p[0];
    const uint32_t n = CellsPerEdge(p, target_size);
    Source src{uint32_t(elements_.size()), n};
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
    auto point = [&](uint32_t i, uint32_t j) { return p[0] + e1 * (float(i) / n) + e2 * (float(j) / n); };
    for (uint32_t i = 0; i <= n; ++i)
        for (uint32_t j = 0; i + j <= n; ++j) grid[gi(i, j)] = Vertex(point(i, j), ng);

    elements_.resize(elements_.size() + size_t(n) * n);
    auto make = [&](uint32_t index, uint32_t a[2], uint32_t b[2], uint32_t c[2]) {
        RadiosityElement& el = elements_[src.first + index];
        const uint32_t* cs[3] = {a, b, c};
        float b1 = 0.f, b2 = 0.f;
        for (int k = 0; k < 3; ++k) {
            el.p[k] = point(cs[k][0], cs[k][1]);
            el.vertex[k] = grid[gi(cs[k][0], cs[k][1])];
            b1 += float(cs[k][0]) / (3.f * n);
            b2 += float(cs[k][1]) / (3.f * n);
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
    for (uint32_t i = 0; i < n; ++i)
        for (uint32_t j = 0; i + j < n; ++j) {
            uint32_t a[2] = {i, j}, b[2] = {i + 1, j}, c[2] = {i, j + 1};
            make(UpCell(n, i, j), a, b, c);
            if (i + j + 1 < n) {
                uint32_t d[2] = {i + 1, j}, e[2] = {i + 1, j + 1}, f[2] = {i, j + 1};
                make(DownCell(n, i, j), d, e, f);
            }
        }
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
    const float x = std::clamp(hit.b1, 0.f, 1.f) * n, y = std::clamp(hit.b2, 0.f, 1.f) * n;
    const uint32_t i = uint32_t(std::clamp(std::floor(x), 0.f, float(n - 1)));
    const uint32_t j = uint32_t(std::clamp(std::floor(y), 0.f, float(n - 1 - i)));
    const float fx = x - float(i), fy = y - float(j);
    if (fx + fy > 1.f && i + j + 1 < n) {
        // Downward cell (i+1, j), (i+1, j+1), (i, j+1).
        w[0] = 1.f - fy;
        w[1] = fx + fy - 1.f;
        w[2] = 1.f - fx;
        return int32_t(src->first + DownCell(n, i, j));
    }
    w[1] = std::clamp(fx, 0.f, 1.f);
    w[2] = std::clamp(fy, 0.f, 1.f - w[1]);
    w[0] = 1.f - w[1] - w[2];
    return int32_t(src->first + UpCell(n, i, j));
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
    return sum;
}

}  // namespace tessera
