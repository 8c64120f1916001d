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

// Reverses the bits of a 32-bit word.
inline uint32_t ReverseBits32(uint32_t v) {
    v = ((v >> 1) & 0x55555555u) | ((v & 0x55555555u) << 1);
    v = ((v >> 2) & 0x33333333u) | ((v & 0x33333333u) << 2);
    v = ((v >> 4) & 0x0F0F0F0Fu) | ((v & 0x0F0F0F0Fu) << 4);
    v = ((v >> 8) & 0x00FF00FFu) | ((v & 0x00FF00FFu) << 8);
    return (v >> 16) | (v << 16);
}

// Hash-based nested uniform (Owen) scrambling of a 32-bit fixed-point value (Burley 2020,
// after Laine and Karras 2011): each bit is flipped by a function of the bits above it
// only, so the scramble maps every aligned dyadic interval onto an aligned dyadic interval
// of the same size. Applied to the bit-reversed word, where multiplication carries bits
// upward, i.e. from more significant to less significant bits of the original.
inline uint32_t OwenScramble(uint32_t v, uint32_t seed) {
    v = ReverseBits32(v);
    v ^= v * 0x3d20adeau;
    v += seed;
    v *= (seed >> 16) | 1u;
    v ^= v * 0x05526c56u;
    v ^= v * 0x53a22864u;
    return ReverseBits32(v);
}

// The first two dimensions of the Sobol sequence, a (0, 2)-sequence: the first 2^k points
// of any aligned block form a (0, k, 2)-net (one point per elementary interval).
inline uint32_t SobolDimension0(uint32_t index) { return ReverseBits32(index); }  // van der Corput
inline uint32_t SobolDimension1(uint32_t index) {
    uint32_t result = 0;
    for (uint32_t v = 1u << 31; index; index >>= 1, v ^= v >> 1)
        if (index & 1u) result ^= v;
    return result;
}

enum class SamplerKind : uint8_t {
    kIndependent,  // a hash per (pixel, sample, dimension): white noise
    kOwenSobol,    // padded Owen-scrambled Sobol: stratified in every 1-D and 2-D projection
};

class PixelSampler {
public:
    // `stream` separates independent uses of the same pixel sample (e.g. its camera path
    // and its light path).
    PixelSampler(uint32_t seed, uint64_t pixel_index, uint32_t sample_index, uint32_t stream = 0,
                 SamplerKind kind = SamplerKind::kIndependent)
        : pixel_key_(Mix64(Mix64(seed + 0x6A09E667F3BCC909ull + (uint64_t(stream) << 32)) ^ pixel_index)),
          key_(Mix64(pixel_key_ ^ sample_index)),
          sample_(sample_index),
          kind_(kind) {}

    // Uniform in [0, 1): 24 random bits, so 1.0f is never returned.
    float Get1D() {
        const uint64_t d = ++dimension_;
        if (kind_ == SamplerKind::kIndependent) return ToUnit(uint32_t(Mix64(key_ + d * 0x9E3779B97F4A7C15ull) >> 32));
        // Padding: every dimension shuffles the sample index with its own scramble, so
        // dimensions are decorrelated while each keeps its stratification.
        const uint64_t h = Mix64(pixel_key_ + d * 0xD1B54A32D192ED03ull);
        const uint32_t index = OwenScramble(sample_, uint32_t(h));
        return ToUnit(OwenScramble(SobolDimension0(index), uint32_t(h >> 32)));
    }
    Vec2 Get2D() {
        if (kind_ == SamplerKind::kIndependent) {
            float a = Get1D();
            return {a, Get1D()};
        }
        const uint64_t d = ++dimension_;
        const uint64_t h = Mix64(pixel_key_ + d * 0xD1B54A32D192ED03ull);
        const uint64_t h2 = Mix64(h);
        const uint32_t index = OwenScramble(sample_, uint32_t(h));
        return {ToUnit(OwenScramble(SobolDimension0(index), uint32_t(h >> 32))),
                ToUnit(OwenScramble(SobolDimension1(index), uint32_t(h2)))};
    }
    uint32_t dimension() const { return dimension_; }

private:
    static float ToUnit(uint32_t bits) { return float(bits >> 8) * 0x1p-24f; }

    uint64_t pixel_key_, key_;
    uint32_t sample_;
    uint32_t dimension_ = 0;
    SamplerKind kind_;
};

}  // namespace tessera
