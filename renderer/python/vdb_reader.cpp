// libtessera_vdb: reads a scalar grid of an OpenVDB file into a dense float array for a
// grid medium (usd/volumes.py, media/density_grid.h), through a C interface that Python
// loads with ctypes: only scenes with volumes load OpenVDB. It exports nothing but that
// interface (vdb_reader.map): Debian's OpenVDB 10 crashed in openvdb::initialize() when
// this library's copies of OpenVDB's template statics were visible to it.
#include <openvdb/openvdb.h>

#include <cstdint>
#include <cstring>
#include <exception>
#include <memory>
#include <string>

namespace {

struct Loaded {
    openvdb::FloatGrid::Ptr grid;
    openvdb::CoordBBox box;  // the active voxels' bounding box
};

void Fail(char* err, int len, const std::string& what) {
    if (len > 0) {
        std::strncpy(err, what.c_str(), size_t(len) - 1);
        err[len - 1] = '\0';
    }
}

}  // namespace

extern "C" {

// Opens grid `name` of `path`: dims (nx, ny, nz) of its active voxels' bounding box, and
// index_to_world, the row-major 4x4 affine (row vectors, USD's convention) from that
// box's index space (voxel (i, j, k) spans [i, i+1] ...,
// its value at the centre) to world space. Returns a handle for tessera_vdb_fill and
// tessera_vdb_free, or null with a message in err.
__attribute__((visibility("default"))) void* tessera_vdb_open(const char* path, const char* name, int64_t* dims,
                                                              double* index_to_world, char* err, int err_len) {
    try {
        openvdb::initialize();
        openvdb::io::File file(path);
        file.open(false);
        if (!file.hasGrid(name)) {
            std::string names;
            for (auto it = file.beginName(); it != file.endName(); ++it) names += (names.empty() ? "" : ", ") + *it;
            Fail(err, err_len, std::string("has no grid named ") + name + " (grids: " + names + ")");
            return nullptr;
        }
        openvdb::GridBase::Ptr base = file.readGrid(name);
        file.close();
        auto loaded = std::make_unique<Loaded>();
        if (auto g = openvdb::GridBase::grid<openvdb::FloatGrid>(base)) {
            loaded->grid = g;
        } else if (auto d = openvdb::GridBase::grid<openvdb::DoubleGrid>(base)) {
            loaded->grid = openvdb::FloatGrid::create(float(d->background()));
            loaded->grid->setTransform(d->transform().copy());
            for (auto it = d->cbeginValueOn(); it; ++it) {
                openvdb::CoordBBox b;
                it.getBoundingBox(b);
                loaded->grid->fill(b, float(*it), true);
            }
        } else {
            Fail(err, err_len, std::string("grid ") + name + " is a " + base->type() + ", not a scalar grid");
            return nullptr;
        }
        const openvdb::math::Transform& xf = loaded->grid->transform();
        if (!xf.isLinear()) {
            Fail(err, err_len, std::string("grid ") + name + " has a non-linear (frustum) transform");
            return nullptr;
        }
        openvdb::CoordBBox box = loaded->grid->evalActiveVoxelBoundingBox();
        if (box.empty()) box = openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(0));
        loaded->box = box;
        const openvdb::Coord dim = box.dim();
        for (int a = 0; a < 3; ++a) dims[a] = dim[a];
        // Our index q has its voxel centre at integer + 0.5: OpenVDB's ijk = q - 0.5 + min.
        const openvdb::Vec3d origin(box.min().x() - 0.5, box.min().y() - 0.5, box.min().z() - 0.5);
        const openvdb::Vec3d p0 = xf.indexToWorld(origin);
        for (int a = 0; a < 3; ++a) {
            openvdb::Vec3d e = origin;
            e[a] += 1.0;
            const openvdb::Vec3d axis = xf.indexToWorld(e) - p0;
            for (int c = 0; c < 3; ++c) index_to_world[4 * a + c] = axis[c];
            index_to_world[4 * a + 3] = 0.0;
        }
        for (int c = 0; c < 3; ++c) index_to_world[12 + c] = p0[c];
        index_to_world[15] = 1.0;
        return loaded.release();
    } catch (const std::exception& e) {
        Fail(err, err_len, e.what());
        return nullptr;
    }
}

// Writes the box's values, (nz, ny, nx) with x fastest, inactive voxels 0.
__attribute__((visibility("default"))) void tessera_vdb_fill(void* handle, float* out) {
    const Loaded& l = *static_cast<Loaded*>(handle);
    const openvdb::Coord lo = l.box.min(), dim = l.box.dim();
    const size_t nx = size_t(dim.x()), ny = size_t(dim.y()), nz = size_t(dim.z());
    std::memset(out, 0, nx * ny * nz * sizeof(float));
    for (auto it = l.grid->cbeginValueOn(); it; ++it) {
        openvdb::CoordBBox b;
        it.getBoundingBox(b);  // a voxel, or a whole tile of one value
        b.intersect(l.box);
        const float v = *it;
        for (int z = b.min().z(); z <= b.max().z(); ++z)
            for (int y = b.min().y(); y <= b.max().y(); ++y)
                for (int x = b.min().x(); x <= b.max().x(); ++x)
                    out[(size_t(z - lo.z()) * ny + size_t(y - lo.y())) * nx + size_t(x - lo.x())] = v;
    }
}

__attribute__((visibility("default"))) void tessera_vdb_free(void* handle) { delete static_cast<Loaded*>(handle); }

}  // extern "C"
