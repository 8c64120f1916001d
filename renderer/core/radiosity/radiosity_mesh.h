// The radiosity mesh: the scene's triangles subdivided into elements no larger than a
// target size, each with constant radiosity on both sides, and display vertices shared
// between the elements that meet there, so the image interpolates radiosity smoothly
// (Cohen & Wallace 1993, ch. 8). The mesh is a pure function of (scene, target size): a
// solver and every tile that reads its solution build the same one, so the solution's
// bytes carry only numbers, never geometry.
#pragma once

#include <cstdint>
#include <unordered_map>
#include <vector>

#include "scene.h"

namespace tessera {

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
    // target_size: the longest edge an element may have (scene units, > 0).
    RadiosityMesh(const Scene& scene, float target_size);

    const std::vector<RadiosityElement>& elements() const { return elements_; }
    // The scene triangles the elements were cut from, in order: the elements of source s
    // are [first, first + n^2), n cuts per edge (hierarchical_solver.cpp refines these).
    struct SourceTriangle {
        Vec3 p[3];
        uint32_t first = 0, n = 1;
    };
    const std::vector<SourceTriangle>& sources() const { return source_list_; }
    size_t num_vertices() const { return num_vertices_; }
    size_t num_source_triangles() const { return num_sources_; }

    // The element a triangle hit lies in and the weights of its three corners there;
    // -1 if the hit is not on a meshed triangle (a sphere light).
    int32_t Locate(const SurfaceHit& hit, float w[3]) const;

    // Per-vertex values from per-element values (one Color per element and side, 2 n):
    // each vertex side is the area-weighted mean of the elements meeting there.
    std::vector<Color> VertexAverage(const std::vector<Color>& element_values) const;

private:
    struct Source {
        uint32_t first = 0;  // its first element
        uint32_t n = 1;      // subdivisions per edge: n^2 elements
    };
    static uint32_t CellsPerEdge(const Vec3 p[3], float target_size);
    void AddSource(const Scene& scene, uint32_t mesh, uint32_t prim, uint32_t instance, const Vec3 p[3], float sign,
                   float target_size);
    uint32_t Vertex(Vec3 p, Vec3 n);

    std::vector<RadiosityElement> elements_;
    std::vector<SourceTriangle> source_list_;
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
