// Subdivision surfaces refined into triangles with OpenSubdiv at translation time, so the
// rest of the renderer only ever sees triangles (one BVH path, one shading path).
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

namespace tessera {

enum class SubdivisionScheme { kCatmullClark = 0, kLoop = 1, kBilinear = 2 };
// Sdc's vertex boundary rules, in the order UsdGeom's interpolateBoundary tokens list them.
enum class SubdivisionBoundary { kNone = 0, kEdgeOnly = 1, kEdgeAndCorner = 2 };

struct SubdivisionCage {
    std::vector<float> points;          // 3 per vertex
    std::vector<int> face_counts;
    std::vector<int> face_indices;
    std::vector<int> crease_edges;      // 2 vertex indices per creased edge
    std::vector<float> crease_sharpness;  // one per creased edge
    std::vector<int> corners;
    std::vector<float> corner_sharpness;
    std::vector<int> holes;             // face indices
    SubdivisionScheme scheme = SubdivisionScheme::kCatmullClark;
    SubdivisionBoundary boundary = SubdivisionBoundary::kEdgeAndCorner;
    bool smooth_triangles = false;      // UsdGeom triangleSubdivisionRule "smooth"
};

// A cage refined uniformly `level` times, its vertices moved to the limit surface.
class SubdivisionSurface {
  public:
    SubdivisionSurface(const SubdivisionCage& cage, int level);
    ~SubdivisionSurface();

    const std::vector<float>& points() const { return points_; }    // limit positions, 3 each
    const std::vector<float>& normals() const { return normals_; }  // limit normals, 3 each
    const std::vector<int>& triangles() const { return triangles_; }
    const std::vector<int>& parent_faces() const { return parent_faces_; }  // cage face per triangle

    // Per-corner values of the cage (one row of `width` per face-vertex, in faceVertexIndices
    // order) refined bilinearly inside each cage face: one row per triangle corner.
    std::vector<float> RefineFaceVarying(const float* values, int width) const;

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
    std::vector<float> points_, normals_;
    std::vector<int> triangles_, parent_faces_;
    // Refined face-vertex slot of each triangle corner (index into the finest level's
    // face-varying values), so face-varying data follows the same fan as the positions.
    std::vector<int> corner_slots_;
};

}  // namespace tessera
