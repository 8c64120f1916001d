// Counter-based pixel sampler.
//
// Invariant (the farm relies on it): dimension d of sample s of pixel p under seed k is a
// pure function of (k, p, s, d). No state is shared between pixels or threads, so an
// image is identical however it is cut into tiles and whichever thread renders a pixel.
#pragma once

#include <cstdint>

#include "math.h"

namespace tessera {

// SplitMix64 finaliser (Steele et al. 2014): a bijective 64-bit mixer with full avalanche.
inline uint64_t Mix64(uint64_t z) {
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

class PixelSampler {
public:
    // `stream` separates independent uses of the same pixel sample (e.g. its camera path
    // and its light path).
    PixelSampler(uint32_t seed, uint64_t pixel_index, uint32_t sample_index, uint32_t stream = 0)
        : key_(Mix64(Mix64(Mix64(seed + 0x6A09E667F3BCC909ull + (uint64_t(stream) << 32)) ^ pixel_index) ^
                     sample_index)) {}

    // Uniform in [0, 1): 24 random bits, so 1.0f is never returned.
    float Get1D() {
        uint64_t h = Mix64(key_ + (++dimension_) * 0x9E3779B97F4A7C15ull);
        return float(h >> 40) * 0x1p-24f;
    }
    Vec2 Get2D() {
        float a = Get1D();
        return {a, Get1D()};
    }
    uint32_t dimension() const { return dimension_; }

private:
    uint64_t key_;
    uint32_t dimension_ = 0;
};

}  // namespace tessera
