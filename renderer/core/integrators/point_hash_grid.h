// A range-search structure over points: a hash grid of cubic cells one search radius wide
// (Teschner et al. 2003's spatial hash), so the points within radius r of x lie in the 27
// cells around x's cell. Built once from a point set and kept as two flat arrays (the
// points sorted by bucket and each bucket's start), which is also its serialised form: a
// scene pass can store it as bytes and a tile pass use it after a copy, with no rebuild.
//
// T is any trivially copyable record with a `float p[3]` position and a `uint8_t
// time_slice` (shutter_slices.h): the hash keys a cell and a slice together, so a lookup
// visits only its own slice's points (a still scene's are all slice 0).
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "math.h"

namespace tessera {

// The bucket of cell (x, y, z) in time slice `slice` among `buckets` (a power of two).
// Slice 0 hashes as the cell alone.
inline uint32_t HashGridBucket(int x, int y, int z, uint32_t slice, uint32_t buckets) {
    const uint32_t h = (uint32_t(x) * 73856093u) ^ (uint32_t(y) * 19349663u) ^ (uint32_t(z) * 83492791u) ^
                       (slice * 2654435761u);
    return h & (buckets - 1);
}

// The buckets of the 27 cells around cell (cx, cy, cz) in `slice`, sorted and each once
// (two cells may share a bucket, whose points must not count twice); returns how many.
inline int NeighbourBuckets(int cx, int cy, int cz, uint32_t slice, uint32_t buckets,
                            std::array<uint32_t, 27>* out) {
    int n = 0;
    for (int dz = -1; dz <= 1; ++dz)
        for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx) (*out)[n++] = HashGridBucket(cx + dx, cy + dy, cz + dz, slice, buckets);
    std::sort(out->begin(), out->end());
    return int(std::unique(out->begin(), out->end()) - out->begin());
}

template <typename T>
class PointHashGrid {
    static_assert(std::is_trivially_copyable_v<T>);

public:
    PointHashGrid() = default;

    // Sorts `points` into buckets by a counting sort that keeps their order within a
    // bucket: the result depends only on the points and the radius.
    PointHashGrid(const std::vector<T>& points, float radius) : radius_(radius) {
        buckets_ = 1;
        while (buckets_ < 2 * uint64_t(points.size()) + 1) buckets_ <<= 1;
        start_.assign(size_t(buckets_) + 1, 0);
        std::vector<uint32_t> bucket_of(points.size());
        for (size_t i = 0; i < points.size(); ++i) {
            bucket_of[i] = HashGridBucket(Cell(points[i].p[0]), Cell(points[i].p[1]), Cell(points[i].p[2]),
                                          points[i].time_slice, buckets_);
            ++start_[bucket_of[i] + 1];
        }
        for (uint32_t b = 0; b < buckets_; ++b) start_[b + 1] += start_[b];
        points_.resize(points.size());
        std::vector<uint32_t> fill(start_.begin(), start_.end() - 1);
        for (size_t i = 0; i < points.size(); ++i) points_[fill[bucket_of[i]]++] = points[i];
    }

    float radius() const { return radius_; }
    size_t size() const { return points_.size(); }
    const std::vector<T>& points() const { return points_; }

    // Calls visit(point) for every point of time slice `slice` within the radius of x,
    // each once.
    template <typename Visit>
    void ForEachNear(Vec3 x, uint32_t slice, Visit&& visit) const {
        if (points_.empty()) return;
        std::array<uint32_t, 27> buckets;
        const int n = NeighbourBuckets(Cell(x.x), Cell(x.y), Cell(x.z), slice, buckets_, &buckets);
        const float r2 = radius_ * radius_;
        for (int b = 0; b < n; ++b)
            for (uint32_t k = start_[buckets[b]]; k < start_[buckets[b] + 1]; ++k) {
                const T& q = points_[k];
                if (q.time_slice != slice) continue;  // another slice's cell in the same bucket
                const Vec3 d(q.p[0] - x.x, q.p[1] - x.y, q.p[2] - x.z);
                if (LengthSquared(d) <= r2) visit(q);
            }
    }

    // Bytes: radius, bucket count, point count, the bucket starts, the points.
    std::string Serialize() const {
        const uint32_t count = uint32_t(points_.size());
        std::string out(sizeof(float) + 2 * sizeof(uint32_t) + start_.size() * sizeof(uint32_t) + count * sizeof(T),
                        '\0');
        char* w = out.data();
        auto put = [&w](const void* src, size_t n) {
            if (n) std::memcpy(w, src, n);
            w += n;
        };
        put(&radius_, sizeof(float));
        put(&buckets_, sizeof(uint32_t));
        put(&count, sizeof(uint32_t));
        put(start_.data(), start_.size() * sizeof(uint32_t));
        put(points_.data(), count * sizeof(T));
        return out;
    }

    // The inverse of Serialize; throws std::invalid_argument on bytes it did not write.
    static PointHashGrid Deserialize(const char* data, size_t size) {
        PointHashGrid g;
        uint32_t count = 0;
        const size_t head = sizeof(float) + 2 * sizeof(uint32_t);
        if (size < head) throw std::invalid_argument("point grid: truncated");
        std::memcpy(&g.radius_, data, sizeof(float));
        std::memcpy(&g.buckets_, data + sizeof(float), sizeof(uint32_t));
        std::memcpy(&count, data + sizeof(float) + sizeof(uint32_t), sizeof(uint32_t));
        if (g.buckets_ == 0 || (g.buckets_ & (g.buckets_ - 1)) != 0 || !(g.radius_ > 0.f))
            throw std::invalid_argument("point grid: bad header");
        const size_t starts = (size_t(g.buckets_) + 1) * sizeof(uint32_t);
        if (size != head + starts + size_t(count) * sizeof(T)) throw std::invalid_argument("point grid: wrong size");
        g.start_.resize(size_t(g.buckets_) + 1);
        std::memcpy(g.start_.data(), data + head, starts);
        if (g.start_.front() != 0 || g.start_.back() != count) throw std::invalid_argument("point grid: bad starts");
        for (uint32_t b = 0; b < g.buckets_; ++b)
            if (g.start_[b] > g.start_[b + 1]) throw std::invalid_argument("point grid: bad starts");
        g.points_.resize(count);
        if (count) std::memcpy(g.points_.data(), data + head + starts, count * sizeof(T));
        return g;
    }

private:
    int Cell(float x) const { return int(std::floor(x / radius_)); }

    float radius_ = 1.f;
    uint32_t buckets_ = 1;
    std::vector<uint32_t> start_{0, 0};
    std::vector<T> points_;
};

}  // namespace tessera
