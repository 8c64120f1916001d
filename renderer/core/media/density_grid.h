// A dense voxel grid of densities (a VDB field translated at scene load, usd/volumes.py)
// with a coarse grid of per-block density bounds for null-scattering tracking.
//
// Index space: voxel (i, j, k) spans [i, i+1] x [j, j+1] x [k, k+1] and its value sits at
// its centre; lookups interpolate trilinearly between centres and hold the edge values out
// to the box [0, nx] x [0, ny] x [0, nz]. Outside the box the density is zero. A VDB's box
// is its active voxels' bounding box (usd/volumes.py): each voxel a cube of its value out
// to the box's faces, so a constant grid is a constant medium (and its tracking exact)
// rather than one that fades over the last half voxel to the background. World points map to index space by an affine map, under which a
// ray's parameter t is unchanged: distances and optical depths stay in world units.
//
// The block bounds (kBlock voxels a side; pbrt-v4 uses 16^3 cells over the whole grid) hold the minimum and
// maximum of every voxel a trilinear lookup inside the block can touch, i.e. the block
// widened by one voxel: the maximum majorises the density, the minimum is the control of
// residual ratio tracking (grid_medium.cpp), exact where a block is constant.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

#include "math.h"

namespace tessera {

struct DensityGrid {
    static constexpr int kBlock = 8;

    int nx = 0, ny = 0, nz = 0;
    std::vector<float> density;  // x fastest: density[(k * ny + j) * nx + i]
    // world -> index space, row-major 3 x 4 (index = M * (world, 1)).
    float world_to_index[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};

    // Block bounds, filled by BuildBlocks().
    int bx = 0, by = 0, bz = 0;
    std::vector<float> block_min, block_max;

    // Checks the sizes and values (finite, >= 0) and builds the block bounds; throws
    // std::invalid_argument naming what is wrong.
    void BuildBlocks();

    Vec3 ToIndex(Vec3 p) const {
        const float* m = world_to_index;
        return {m[0] * p.x + m[1] * p.y + m[2] * p.z + m[3], m[4] * p.x + m[5] * p.y + m[6] * p.z + m[7],
                m[8] * p.x + m[9] * p.y + m[10] * p.z + m[11]};
    }
    Vec3 DirectionToIndex(Vec3 d) const {
        const float* m = world_to_index;
        return {m[0] * d.x + m[1] * d.y + m[2] * d.z, m[4] * d.x + m[5] * d.y + m[6] * d.z,
                m[8] * d.x + m[9] * d.y + m[10] * d.z};
    }

    float Voxel(int i, int j, int k) const {
        i = i < 0 ? 0 : (i >= nx ? nx - 1 : i);
        j = j < 0 ? 0 : (j >= ny ? ny - 1 : j);
        k = k < 0 ? 0 : (k >= nz ? nz - 1 : k);
        return density[(size_t(k) * size_t(ny) + size_t(j)) * size_t(nx) + size_t(i)];
    }
    // The trilinear density at an index-space point (zero outside the box).
    float Lookup(Vec3 q) const {
        if (!(q.x >= 0.f && q.y >= 0.f && q.z >= 0.f && q.x <= float(nx) && q.y <= float(ny) && q.z <= float(nz)))
            return 0.f;
        const float x = q.x - 0.5f, y = q.y - 0.5f, z = q.z - 0.5f;
        const float fx = std::floor(x), fy = std::floor(y), fz = std::floor(z);
        const int i = int(fx), j = int(fy), k = int(fz);
        const float ax = x - fx, ay = y - fy, az = z - fz;
        auto lerp = [](float a, float u, float v) { return (1.f - a) * u + a * v; };
        const float c00 = lerp(ax, Voxel(i, j, k), Voxel(i + 1, j, k));
        const float c10 = lerp(ax, Voxel(i, j + 1, k), Voxel(i + 1, j + 1, k));
        const float c01 = lerp(ax, Voxel(i, j, k + 1), Voxel(i + 1, j, k + 1));
        const float c11 = lerp(ax, Voxel(i, j + 1, k + 1), Voxel(i + 1, j + 1, k + 1));
        return lerp(az, lerp(ay, c00, c10), lerp(ay, c01, c11));
    }

    size_t Bytes() const { return (density.size() + block_min.size() + block_max.size()) * sizeof(float); }

    // Visits the blocks a ray (index-space origin o and direction d, world parameter t)
    // crosses between t0 and t1, in order: visit(ta, tb, min, max) -> false stops.
    template <typename Visit>
    void ForEachBlock(Vec3 o, Vec3 d, float t0, float t1, Visit&& visit) const;
};

template <typename Visit>
void DensityGrid::ForEachBlock(Vec3 o, Vec3 d, float t0, float t1, Visit&& visit) const {
    // Clip to the box, then step block by block (Amanatides and Woo) in block units.
    const float lo[3] = {0.f, 0.f, 0.f}, hi[3] = {float(nx), float(ny), float(nz)};
    const float oo[3] = {o.x, o.y, o.z}, dd[3] = {d.x, d.y, d.z};
    for (int a = 0; a < 3; ++a) {
        if (dd[a] == 0.f) {
            if (oo[a] < lo[a] || oo[a] > hi[a]) return;
            continue;
        }
        float ta = (lo[a] - oo[a]) / dd[a], tb = (hi[a] - oo[a]) / dd[a];
        if (ta > tb) std::swap(ta, tb);
        t0 = std::max(t0, ta);
        t1 = std::min(t1, tb);
    }
    if (!(t0 < t1)) return;
    const int nb[3] = {bx, by, bz};
    int cell[3], step[3];
    float next[3], delta[3];
    for (int a = 0; a < 3; ++a) {
        const float p = (oo[a] + dd[a] * t0) / float(kBlock);
        cell[a] = std::min(std::max(int(std::floor(p)), 0), nb[a] - 1);
        if (dd[a] == 0.f) {
            step[a] = 0;
            next[a] = delta[a] = std::numeric_limits<float>::infinity();
            continue;
        }
        const float inv = float(kBlock) / dd[a];  // t per block along this axis
        step[a] = dd[a] > 0.f ? 1 : -1;
        const float edge = float(cell[a] + (dd[a] > 0.f ? 1 : 0)) * float(kBlock);
        next[a] = (edge - oo[a]) / dd[a];
        delta[a] = std::abs(inv);
    }
    float t = t0;
    while (t < t1) {
        const int axis = next[0] < next[1] ? (next[0] < next[2] ? 0 : 2) : (next[1] < next[2] ? 1 : 2);
        const float tb = std::min(std::max(next[axis], t), t1);
        const size_t b = (size_t(cell[2]) * size_t(by) + size_t(cell[1])) * size_t(bx) + size_t(cell[0]);
        if (!visit(t, tb, block_min[b], block_max[b])) return;
        t = tb;
        cell[axis] += step[axis];
        if (cell[axis] < 0 || cell[axis] >= nb[axis]) return;
        next[axis] += delta[axis];
    }
}

}  // namespace tessera
