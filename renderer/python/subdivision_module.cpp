// Python binding of the subdivision refiner: the USD translator hands over a cage as flat
// numpy arrays and gets triangles back. Its own module so it builds apart from the renderer's.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/vector.h>

#include <memory>
#include <stdexcept>

#include "subdivision.h"

namespace nb = nanobind;
using namespace nb::literals;
using namespace tessera;

namespace {

template <typename T>
using In = nb::ndarray<const T, nb::c_contig, nb::device::cpu>;

template <typename T>
std::vector<T> ToVector(const In<T>& a) {
    return std::vector<T>(a.data(), a.data() + a.size());
}

// Hands a vector to numpy without a copy; the capsule owns it.
template <typename T>
nb::ndarray<nb::numpy, T> ToArray(std::vector<T> v, size_t cols) {
    auto* owned = new std::vector<T>(std::move(v));
    nb::capsule owner(owned, [](void* p) noexcept { delete static_cast<std::vector<T>*>(p); });
    size_t shape[2] = {cols ? owned->size() / cols : owned->size(), cols};
    return nb::ndarray<nb::numpy, T>(owned->data(), cols ? 2 : 1, shape, owner);
}

}  // namespace

NB_MODULE(_subdivision, m) {
    nb::class_<SubdivisionSurface>(m, "SubdivisionSurface",
        "A cage refined uniformly `level` times with OpenSubdiv, vertices on the limit surface.\n"
        "scheme: 0 Catmull-Clark, 1 Loop, 2 bilinear; boundary: 0 none, 1 edgeOnly, 2 edgeAndCorner.")
        .def("__init__",
             [](SubdivisionSurface* self, In<float> points, In<int> face_counts, In<int> face_indices,
                int level, int scheme, int boundary, bool smooth_triangles, In<int> crease_edges,
                In<float> crease_sharpness, In<int> corners, In<float> corner_sharpness, In<int> holes) {
                 SubdivisionCage cage;
                 cage.points = ToVector(points);
                 cage.face_counts = ToVector(face_counts);
                 cage.face_indices = ToVector(face_indices);
                 cage.crease_edges = ToVector(crease_edges);
                 cage.crease_sharpness = ToVector(crease_sharpness);
                 cage.corners = ToVector(corners);
                 cage.corner_sharpness = ToVector(corner_sharpness);
                 cage.holes = ToVector(holes);
                 if (scheme < 0 || scheme > 2 || boundary < 0 || boundary > 2)
                     throw std::invalid_argument("unknown subdivision scheme or boundary rule");
                 if (cage.crease_edges.size() != 2 * cage.crease_sharpness.size() ||
                     cage.corners.size() != cage.corner_sharpness.size())
                     throw std::invalid_argument("crease or corner arrays disagree in length");
                 cage.scheme = SubdivisionScheme(scheme);
                 cage.boundary = SubdivisionBoundary(boundary);
                 cage.smooth_triangles = smooth_triangles;
                 nb::gil_scoped_release release;
                 new (self) SubdivisionSurface(cage, level);
             },
             "points"_a, "face_counts"_a, "face_indices"_a, "level"_a, "scheme"_a, "boundary"_a,
             "smooth_triangles"_a, "crease_edges"_a, "crease_sharpness"_a, "corners"_a,
             "corner_sharpness"_a, "holes"_a)
        .def("points", [](const SubdivisionSurface& s) { return ToArray(s.points(), 3); })
        .def("normals", [](const SubdivisionSurface& s) { return ToArray(s.normals(), 3); })
        .def("triangles", [](const SubdivisionSurface& s) { return ToArray(s.triangles(), 3); })
        .def("parent_faces", [](const SubdivisionSurface& s) { return ToArray(s.parent_faces(), 0); })
        .def("refine_face_varying",
             [](const SubdivisionSurface& s, In<float> values, int width) {
                 return ToArray(s.RefineFaceVarying(values.data(), width), size_t(width));
             },
             "values"_a, "width"_a,
             "Per-corner cage values (one row per faceVertexIndices entry) refined bilinearly inside "
             "each cage face: one row per triangle corner, (3 * triangles, width).");
}
