#include "subdivision.h"

#include <opensubdiv/far/primvarRefiner.h>
#include <opensubdiv/far/topologyDescriptor.h>
#include <opensubdiv/far/topologyRefinerFactory.h>

#include <cmath>
#include <numeric>
#include <stdexcept>

namespace tessera {

namespace {

using namespace OpenSubdiv;

// A row of `width` floats inside a flat buffer: the vertex interface PrimvarRefiner needs.
struct Row {
    float* p;
    int width;
    void Clear() {
        for (int i = 0; i < width; ++i) p[i] = 0.0f;
    }
    void AddWithWeight(const Row& src, float weight) {
        for (int i = 0; i < width; ++i) p[i] += weight * src.p[i];
    }
};

struct Rows {
    float* base;
    int width;
    Row operator[](int i) const { return Row{base + size_t(i) * width, width}; }
};

Sdc::SchemeType ToSdc(SubdivisionScheme s) {
    switch (s) {
        case SubdivisionScheme::kLoop: return Sdc::SCHEME_LOOP;
        case SubdivisionScheme::kBilinear: return Sdc::SCHEME_BILINEAR;
        default: return Sdc::SCHEME_CATMARK;
    }
}

Sdc::Options::VtxBoundaryInterpolation ToSdc(SubdivisionBoundary b) {
    switch (b) {
        case SubdivisionBoundary::kNone: return Sdc::Options::VTX_BOUNDARY_NONE;
        case SubdivisionBoundary::kEdgeOnly: return Sdc::Options::VTX_BOUNDARY_EDGE_ONLY;
        default: return Sdc::Options::VTX_BOUNDARY_EDGE_AND_CORNER;
    }
}

}  // namespace

struct SubdivisionSurface::Impl {
    std::unique_ptr<Far::TopologyRefiner> refiner;
    int level = 0;
};

SubdivisionSurface::SubdivisionSurface(const SubdivisionCage& cage, int level) : impl_(new Impl) {
    if (level < 1) throw std::invalid_argument("subdivision level must be at least 1");
    const int num_vertices = int(cage.points.size() / 3);
    const int num_corners = int(cage.face_indices.size());

    Far::TopologyDescriptor desc;
    desc.numVertices = num_vertices;
    desc.numFaces = int(cage.face_counts.size());
    desc.numVertsPerFace = cage.face_counts.data();
    desc.vertIndicesPerFace = cage.face_indices.data();
    desc.numCreases = int(cage.crease_sharpness.size());
    desc.creaseVertexIndexPairs = cage.crease_edges.data();
    desc.creaseWeights = cage.crease_sharpness.data();
    desc.numCorners = int(cage.corner_sharpness.size());
    desc.cornerVertexIndices = cage.corners.data();
    desc.cornerWeights = cage.corner_sharpness.data();
    desc.numHoles = int(cage.holes.size());
    desc.holeIndices = cage.holes.data();
    // One face-varying channel with a value per face-vertex: every cage face owns its
    // values, so face-varying data is interpolated inside each face and never across.
    std::vector<int> slots(num_corners);
    std::iota(slots.begin(), slots.end(), 0);
    Far::TopologyDescriptor::FVarChannel channel;
    channel.numValues = num_corners;
    channel.valueIndices = slots.data();
    desc.numFVarChannels = 1;
    desc.fvarChannels = &channel;

    Sdc::Options options;
    options.SetVtxBoundaryInterpolation(ToSdc(cage.boundary));
    options.SetFVarLinearInterpolation(Sdc::Options::FVAR_LINEAR_ALL);
    options.SetTriangleSubdivision(cage.smooth_triangles ? Sdc::Options::TRI_SUB_SMOOTH
                                                         : Sdc::Options::TRI_SUB_CATMARK);
    using Factory = Far::TopologyRefinerFactory<Far::TopologyDescriptor>;
    impl_->refiner.reset(Factory::Create(desc, Factory::Options(ToSdc(cage.scheme), options)));
    if (!impl_->refiner) throw std::invalid_argument("OpenSubdiv rejected the mesh topology");
    Far::TopologyRefiner::UniformOptions uniform(level);
    uniform.fullTopologyInLastLevel = true;  // Limit() needs every vertex's neighbourhood
    impl_->refiner->RefineUniform(uniform);
    impl_->level = level;

    // Positions level by level, then the finest level's vertices pushed to the limit.
    Far::PrimvarRefiner primvars(*impl_->refiner);
    std::vector<float> src(cage.points), dst;
    for (int l = 1; l <= level; ++l) {
        dst.assign(size_t(impl_->refiner->GetLevel(l).GetNumVertices()) * 3, 0.0f);
        Rows from{src.data(), 3}, to{dst.data(), 3};
        primvars.Interpolate(l, from, to);
        src.swap(dst);
    }
    const size_t n = src.size() / 3;
    points_.assign(n * 3, 0.0f);
    std::vector<float> du(n * 3), dv(n * 3);
    Rows fine_rows{src.data(), 3}, limit_rows{points_.data(), 3}, du_rows{du.data(), 3}, dv_rows{dv.data(), 3};
    primvars.Limit(fine_rows, limit_rows, du_rows, dv_rows);
    normals_.assign(n * 3, 0.0f);
    for (size_t i = 0; i < n; ++i) {
        const float* a = &du[i * 3];
        const float* b = &dv[i * 3];
        float c[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
        const float len = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
        for (int k = 0; k < 3; ++k) normals_[i * 3 + k] = len > 0.0f ? c[k] / len : 0.0f;
    }

    // Parent cage face of every finest face, composed level by level.
    std::vector<int> parent(cage.face_counts.size());
    std::iota(parent.begin(), parent.end(), 0);
    for (int l = 1; l <= level; ++l) {
        std::vector<int> child(impl_->refiner->GetLevel(l).GetNumFaces());
        primvars.InterpolateFaceUniform(l, parent, child);
        parent.swap(child);
    }

    // Finest faces as triangle fans (quads for Catmull-Clark, triangles for Loop).
    const Far::TopologyLevel& fine = impl_->refiner->GetLevel(level);
    for (int f = 0; f < fine.GetNumFaces(); ++f) {
        Far::ConstIndexArray verts = fine.GetFaceVertices(f);
        Far::ConstIndexArray fvars = fine.GetFaceFVarValues(f, 0);
        if (!fine.IsFaceHole(f)) {
            for (int k = 1; k + 1 < verts.size(); ++k) {
                for (int c : {0, k, k + 1}) {
                    triangles_.push_back(verts[c]);
                    corner_slots_.push_back(fvars[c]);
                }
                parent_faces_.push_back(parent[f]);
            }
        }
    }
}

SubdivisionSurface::~SubdivisionSurface() = default;

std::vector<float> SubdivisionSurface::RefineFaceVarying(const float* values, int width) const {
    Far::PrimvarRefiner primvars(*impl_->refiner);
    std::vector<float> src(values, values + size_t(impl_->refiner->GetLevel(0).GetNumFVarValues(0)) * width);
    std::vector<float> dst;
    for (int l = 1; l <= impl_->level; ++l) {
        dst.assign(size_t(impl_->refiner->GetLevel(l).GetNumFVarValues(0)) * width, 0.0f);
        Rows from{src.data(), width}, to{dst.data(), width};
        primvars.InterpolateFaceVarying(l, from, to, 0);
        src.swap(dst);
    }
    std::vector<float> out(corner_slots_.size() * width);
    for (size_t i = 0; i < corner_slots_.size(); ++i)
        for (int k = 0; k < width; ++k) out[i * width + k] = src[size_t(corner_slots_[i]) * width + k];
    return out;
}

}  // namespace tessera
