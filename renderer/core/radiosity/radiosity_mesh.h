// The radiosity mesh: the scene's triangles subdivided into elements no larger than a
// target size, each with constant radiosity on both sides, and display vertices shared
// between the elements that meet there, so the image interpolates radiosity smoothly
// (Cohen & Wallace 1993, ch. 8). The mesh is a pure function of (scene, target size,
// refinement): a solver and every tile that reads its solution build the same one, so the
// solution's bytes carry only numbers (and the refinement depths), never geometry.
//
// Adaptive refinement (Cohen & Wallace ch. 8.3): each uniform cell of a source triangle is
// the root of a quadtree of midpoint subdivisions (children: the three corner triangles,
// then the inverted middle one), at most kMaxDepth deep, whose leaves are the elements;
// leaves are split where the radiosity varies fast (shadow boundaries). A refined mesh is
// named by its leaves' depths in preorder, one byte per element. Where a finer leaf meets
// a coarser one, the finer side's edge vertices are hanging (T-vertices): the display gives
// them the value interpolated along the coarse edge, so the image stays continuous.
#pragma once

#include <algorithm>
#include <cstdint>
#include <unordered_map>
#include <vector>

#include "scene.h"

namespace tessera {

// The length by which radiosity's shadow rays leave their surfaces and below which its
// vertices weld: a ten-thousandth of the scene's radius, and at least 2^-16 of its
// coordinates' magnitude (about 128 float steps there, for a small scene far from the
// origin). It was 1e-4 max(1, radius), at least 1e-4 scene units: on the integrator
// matrix's rect-lit plane scaled by 1e-3 (2e-3 wide, refined elements about 3e-5) it
// welded vertices 1e-4 apart, and one region read 1.79 % low where the same plane at
// scale 1 read 0.28 % low.
inline float RadiosityLengthScale(const Scene& scene) {
    const float r = scene.scene_radius();
    return std::max(1e-4f * r, 0x1p-16f * (Length(scene.scene_center()) + r));
}

struct RadiosityElement {
    Vec3 p[3];     // world-space corners, wound like the source triangle
    Vec3 n;        // unit facing normal (the side one-sided emission leaves): side 0
    Vec3 center;
    float area = 0.f;
    // The reflectance radiosity uses: the bihemispherical reflectance of the material's
    // non-delta lobes (a Lambertian's albedo; radiosity_mesh.cpp).
    Color rho;
    Color emission[2];     // emitted radiosity pi Le (W m^-2) on the front (0) and back (1)
    uint32_t vertex[3] = {0, 0, 0};  // display vertices of the corners
    int32_t emitter = -1;  // the scene emitter of the source triangle, or -1
};

class RadiosityMesh {
public:
    // More elements than this are refused (memory: the solution and display per element).
    static constexpr uint64_t kMaxElements = uint64_t(1) << 22;
    static constexpr uint8_t kMaxDepth = 3;
    // target_size: the longest edge an element may have (scene units, > 0). leaf_depth: per
    // element, its depth in its cell's quadtree, in preorder (empty: every cell is one
    // element). Throws std::invalid_argument if the depths do not tile the cells.
    RadiosityMesh(const Scene& scene, float target_size, const std::vector<uint8_t>& leaf_depth = {});

    const std::vector<RadiosityElement>& elements() const { return elements_; }
    // The scene triangles the elements were cut from, in order: the uniform cells of source
    // s are [first, first + n^2), n cuts per edge (hierarchical_solver.cpp refines these;
    // in an unrefined mesh cells and elements are the same).
    struct SourceTriangle {
        Vec3 p[3];
        uint32_t first = 0, n = 1;
    };
    size_t num_cells() const { return num_cells_; }
    // Per element, its depth in its cell's quadtree (empty when not refined).
    const std::vector<uint8_t>& leaf_depth() const { return leaf_depth_; }
    bool refined() const { return !leaf_depth_.empty(); }
    // The elements of uniform cell c are [CellFirst(c), CellFirst(c + 1)).
    size_t CellFirst(size_t c) const { return cell_first_.empty() ? c : cell_first_[c]; }
    // A hanging vertex v takes (1 - t) value(a) + t value(b) in the display; listed
    // coarse edges first, so a and b are settled before v.
    struct HangingVertex {
        uint32_t v, a, b;
        float t;
    };
    const std::vector<HangingVertex>& hanging_vertices() const { return hanging_; }
    const std::vector<SourceTriangle>& sources() const { return source_list_; }
    size_t num_vertices() const { return num_vertices_; }
    size_t num_source_triangles() const { return num_sources_; }

    // The element a triangle hit lies in and the weights of its three corners there;
    // -1 if the hit is not on a meshed triangle (a sphere light).
    int32_t Locate(const SurfaceHit& hit, float w[3]) const;

    // Per-vertex values from per-element values (one Color per element and side, 2 n):
    // each vertex side is the area-weighted mean of the elements meeting there, a hanging
    // vertex the interpolation along its coarse edge.
    std::vector<Color> VertexAverage(const std::vector<Color>& element_values) const;
    // Gives each hanging vertex side (2 v + side) of per-vertex values the interpolation
    // along its coarse edge, as VertexAverage does, so the display does not step there.
    void SettleHanging(std::vector<Color>* vertex_values) const;

private:
    struct Source {
        uint32_t first = 0;  // its first uniform cell
        uint32_t n = 1;      // subdivisions per edge: n^2 cells
    };
    static uint32_t CellsPerEdge(const Vec3 p[3], float target_size);
    void AddSource(const Scene& scene, uint32_t mesh, uint32_t prim, uint32_t instance, const Vec3 p[3], float sign,
                   float target_size);
    uint32_t Vertex(Vec3 p, Vec3 n);
    int64_t FindVertex(Vec3 p, Vec3 n) const;  // -1 if none was made there
    void FindHangingVertices();

    std::vector<RadiosityElement> elements_;
    std::vector<SourceTriangle> source_list_;
    std::vector<uint8_t> leaf_depth_;
    std::vector<uint8_t> leaf_offset_;  // per element: its first finest cell in its cell (preorder)
    std::vector<uint32_t> cell_first_;  // num_cells_ + 1 entries when refined
    std::vector<HangingVertex> hanging_;
    size_t num_cells_ = 0;
    std::vector<Source> world_;                           // world mesh, by prim
    std::unordered_map<uint64_t, Source> instanced_;      // (instance, prim)
    struct VertexKey {
        int64_t x, y, z, normal;
        bool operator==(const VertexKey&) const = default;
    };
    struct VertexKeyHash {
        size_t operator()(const VertexKey& k) const {
            uint64_t h = 1469598103934665603ull;
            for (int64_t v : {k.x, k.y, k.z, k.normal}) h = (h ^ uint64_t(v)) * 1099511628211ull;
            return size_t(h);
        }
    };
    // Welding: quantised position and normal -> vertex (only while building).
    std::unordered_map<VertexKey, uint32_t, VertexKeyHash> vertex_index_;
    std::unordered_map<const Material*, Color> reflectance_;  // per material (only while building)
    size_t num_vertices_ = 0;
    size_t num_sources_ = 0;
    float quantum_ = 1e-5f;
};

// Index of the element of subdivision cell (i, j) of a source triangle cut n times per
// edge: the n (n + 1) / 2 upward cells first, then the n (n - 1) / 2 downward ones.
inline uint32_t UpCell(uint32_t n, uint32_t i, uint32_t j) { return i * n - i * (i - 1) / 2 + j; }
inline uint32_t DownCell(uint32_t n, uint32_t i, uint32_t j) {
    return n * (n + 1) / 2 + i * (n - 1) - i * (i - 1) / 2 + j;
}

}  // namespace tessera
