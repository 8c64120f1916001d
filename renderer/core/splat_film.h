// Full-frame accumulator for light-tracing splats: contributions that land on any pixel
// of the image, wherever the tile that traced them is.
//
// Invariant: the accumulated value does not depend on the order of additions. Splats are
// added as 64-bit fixed point (integer addition is associative), so tiles rendered in any
// order, on any number of threads or machines, sum to exactly the same frame. A float sum
// would differ in its last bits with the order.
#pragma once

#include <atomic>
#include <cmath>
#include <cstdint>

#include "math.h"

namespace tessera {

// Fixed point relative to the scene's unit 2^e (Scene::splat_exponent): a value v is
// stored as round(v * kSplatScale / 2^e), so the resolution is 2^(e-24) and one splat may
// reach 2^(e+39) before it is refused. Stored = value * SplatScale(e).
inline constexpr double kSplatScale = 16777216.0;  // 2^24
inline double SplatScale(int exponent) { return std::ldexp(kSplatScale, -exponent); }

class SplatFilm {
public:
    // `data` holds width * height * 3 int64 (RGB), zeroed by the caller. `also`, if not
    // null, is a second such buffer that receives every splat too (a variance batch's).
    SplatFilm(int64_t* data, uint32_t width, uint32_t height, int exponent = 0, int64_t* also = nullptr)
        : data_(data), also_(also), width_(width), height_(height), scale_(SplatScale(exponent)),
          keep_w_(width), keep_h_(height) {}

    // Keeps only the splats landing in [x0, x0 + w) x [y0, y0 + h) (a crop: the pixels
    // outside it are not wanted); the others are dropped as accepted, not as bad splats.
    void KeepOnly(uint32_t x0, uint32_t y0, uint32_t w, uint32_t h) {
        keep_x0_ = x0, keep_y0_ = y0, keep_w_ = w, keep_h_ = h;
    }

    // Adds `value` at continuous raster position (px, py); safe from many threads.
    // Returns false (adding nothing) for a value that is not finite and >= 0, or too large
    // to represent; the caller counts that as a bad sample.
    bool Add(float px, float py, Color value) {
        if (!(px >= 0.f) || !(py >= 0.f)) return false;
        uint32_t x = uint32_t(px), y = uint32_t(py);
        if (x >= width_ || y >= height_) return false;
        int64_t q[3];
        for (int c = 0; c < 3; ++c) {
            double v = double(value[c]) * scale_;
            if (!(v >= 0.0) || !(v < 9.0e18)) return false;  // NaN, negative, or overflow
            q[c] = std::llround(v);
        }
        if (x - keep_x0_ >= keep_w_ || y - keep_y0_ >= keep_h_) return true;
        const size_t at = 3 * (size_t(y) * width_ + x);
        for (int64_t* buffer : {data_, also_}) {
            if (!buffer) continue;
            for (int c = 0; c < 3; ++c)
                if (q[c]) std::atomic_ref<int64_t>(buffer[at + c]).fetch_add(q[c], std::memory_order_relaxed);
        }
        return true;
    }

    uint32_t width() const { return width_; }
    uint32_t height() const { return height_; }

private:
    int64_t* data_;
    int64_t* also_;
    uint32_t width_, height_;
    double scale_;
    uint32_t keep_x0_ = 0, keep_y0_ = 0, keep_w_, keep_h_;
};

}  // namespace tessera
