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

// Reverses the bits of a 32-bit word: the byte order by one bswap, then the bits within
// each byte.
inline uint32_t ReverseBits32(uint32_t v) {
    v = __builtin_bswap32(v);
    v = ((v >> 1) & 0x55555555u) | ((v & 0x55555555u) << 1);
    v = ((v >> 2) & 0x33333333u) | ((v & 0x33333333u) << 2);
    return ((v >> 4) & 0x0F0F0F0Fu) | ((v & 0x0F0F0F0Fu) << 4);
}

// Hash-based nested uniform (Owen) scrambling of a 32-bit fixed-point value (Burley 2020,
// after Laine and Karras 2011): each bit is flipped by a function of the bits above it
// only, so the scramble maps every aligned dyadic interval onto an aligned dyadic interval
// of the same size. The hash works on the bit-reversed word, where multiplication carries
// bits upward, i.e. from more significant to less significant bits of the original:
//   OwenScramble(v, seed) = ReverseBits32(OwenHashReversed(ReverseBits32(v), seed)).
// The sampler composes the two halves itself, so that reversals which cancel (Sobol's
// first dimension is itself a reversal) are never computed.
inline uint32_t OwenHashReversed(uint32_t v, uint32_t seed) {
    v ^= v * 0x3d20adeau;
    v += seed;
    v *= (seed >> 16) | 1u;
    v ^= v * 0x05526c56u;
    v ^= v * 0x53a22864u;
    return v;
}
inline uint32_t OwenScramble(uint32_t v, uint32_t seed) {
    return ReverseBits32(OwenHashReversed(ReverseBits32(v), seed));
}

// The first two dimensions of the Sobol sequence, a (0, 2)-sequence: the first 2^k points
// of any aligned block form a (0, k, 2)-net (one point per elementary interval).
inline uint32_t SobolDimension0(uint32_t index) { return ReverseBits32(index); }  // van der Corput
// Dimension 1 XORs one direction number per set bit of the index, v_0 = 2^31 and
// v_{b+1} = v_b ^ (v_b >> 1). The scrambled indices the sampler passes have ~16 of 32 bits
// set at random, so a loop over bits mispredicts; the XOR of each byte's direction numbers
// is tabulated instead (4 x 256 words, built at compile time).
namespace sobol_detail {
struct Dimension1Table {
    uint32_t t[4][256];
    uint32_t reversed[4][256];  // the same words bit-reversed (XOR commutes with reversal)
};
constexpr Dimension1Table MakeDimension1Table() {
    Dimension1Table table{};
    uint32_t v[32] = {};
    v[0] = 1u << 31;
    for (int b = 1; b < 32; ++b) v[b] = v[b - 1] ^ (v[b - 1] >> 1);
    for (int k = 0; k < 4; ++k)
        for (uint32_t byte = 0; byte < 256; ++byte) {
            uint32_t x = 0;
            for (int bit = 0; bit < 8; ++bit)
                if (byte & (1u << bit)) x ^= v[8 * k + bit];
            table.t[k][byte] = x;
            uint32_t r = 0;
            for (int bit = 0; bit < 32; ++bit) r |= ((x >> bit) & 1u) << (31 - bit);
            table.reversed[k][byte] = r;
        }
    return table;
}
inline constexpr Dimension1Table kDimension1 = MakeDimension1Table();
}  // namespace sobol_detail

inline uint32_t SobolDimension1(uint32_t index) {
    const auto& t = sobol_detail::kDimension1.t;
    return t[0][index & 0xFFu] ^ t[1][(index >> 8) & 0xFFu] ^ t[2][(index >> 16) & 0xFFu] ^ t[3][index >> 24];
}
// ReverseBits32(SobolDimension1(index)), from the reversed table.
inline uint32_t SobolDimension1Reversed(uint32_t index) {
    const auto& t = sobol_detail::kDimension1.reversed;
    return t[0][index & 0xFFu] ^ t[1][(index >> 8) & 0xFFu] ^ t[2][(index >> 16) & 0xFFu] ^ t[3][index >> 24];
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
          reversed_sample_(ReverseBits32(sample_index)),
          kind_(kind) {}

    // Uniform in [0, 1): 24 random bits, so 1.0f is never returned.
    float Get1D() {
        const uint64_t d = ++dimension_;
        if (kind_ == SamplerKind::kIndependent) return ToUnit(uint32_t(Mix64(key_ + d * 0x9E3779B97F4A7C15ull) >> 32));
        // Padding: every dimension shuffles the sample index with its own scramble, so
        // dimensions are decorrelated while each keeps its stratification.
        const uint64_t h = Mix64(pixel_key_ + d * 0xD1B54A32D192ED03ull);
        return ToUnit(ScrambledDimension0(ShuffledIndex(uint32_t(h)), uint32_t(h >> 32)));
    }
    Vec2 Get2D() {
        if (kind_ == SamplerKind::kIndependent) {
            float a = Get1D();
            return {a, Get1D()};
        }
        const uint64_t d = ++dimension_;
        const uint64_t h = Mix64(pixel_key_ + d * 0xD1B54A32D192ED03ull);
        const uint64_t h2 = Mix64(h);
        const uint32_t index = ShuffledIndex(uint32_t(h));
        return {ToUnit(ScrambledDimension0(index, uint32_t(h >> 32))),
                ToUnit(ReverseBits32(OwenHashReversed(SobolDimension1Reversed(index), uint32_t(h2))))};
    }
    uint32_t dimension() const { return dimension_; }

private:
    static float ToUnit(uint32_t bits) { return float(bits >> 8) * 0x1p-24f; }
    // OwenScramble(sample index, seed): the padding shuffle of one dimension.
    uint32_t ShuffledIndex(uint32_t seed) const { return ReverseBits32(OwenHashReversed(reversed_sample_, seed)); }
    // OwenScramble(SobolDimension0(index), seed): Sobol's first dimension is the bit
    // reversal of the index, which the scramble's own first reversal undoes.
    static uint32_t ScrambledDimension0(uint32_t index, uint32_t seed) {
        return ReverseBits32(OwenHashReversed(index, seed));
    }

    uint64_t pixel_key_, key_;
    uint32_t reversed_sample_;  // ReverseBits32(sample index): the only form the scrambles read
    uint32_t dimension_ = 0;
    SamplerKind kind_;
};

}  // namespace tessera
