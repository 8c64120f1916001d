// Image textures for UsdUVTexture: linear float images, bilinear lookups with the
// schema's wrap modes, scale/bias/fallback, channel outputs, UsdTransform2d and UDIM tiles,
// and filtered lookups over a footprint from a mip-map pyramid built once per image.
//
// Images arrive decoded (Python reads files with OpenImageIO, inside the bundle sandbox,
// and hands over float texels), so the core never parses untrusted image files. The one
// colour-space step that belongs to texture semantics, sRGB decoding, happens here when a
// TextureSet is built, on the colour channels only (alpha is always linear).
//
// Conventions (UsdPreviewSurface spec): st (0, 0) is the image's lower-left corner, texel
// centres sit at half-integers, and `fallback` is returned unscaled wherever there is no
// image data (missing UDIM tile, non-finite st). Channels missing from an image follow
// Storm's swizzle: grey -> (g, g, g, 1), grey+alpha -> (g, g, g, a), rgb -> (r, g, b, 1).
#pragma once

#include <array>
#include <cstdint>
#include <map>
#include <utility>
#include <vector>

#include "math.h"

namespace tessera {

using RGBA = std::array<float, 4>;

enum class WrapMode : uint8_t { kRepeat, kClamp, kMirror, kBlack };
enum class TextureOutput : uint8_t { kR, kG, kB, kA, kRGB };

// The sRGB transfer function's inverse (IEC 61966-2-1), for one encoded value in [0, 1].
float SrgbToLinear(float encoded);

struct Image {
    uint32_t width = 0, height = 0, channels = 0;  // channels 1..4
    std::vector<float> texels;                    // rows top to bottom, channels interleaved
    bool srgb = false;                            // colour channels are sRGB-encoded
};

// A lookup's footprint: the st offsets of one pixel step along two directions on the
// surface (pbrt's dst/dx and dst/dy). Zero is a point lookup: bilinear on the finest level.
struct TextureFootprint {
    Vec2 dx, dy;
};

struct TextureDesc {
    int32_t image = -1;               // the image, for a texture without UDIM tiles
    std::vector<int32_t> udim_tiles;  // empty, or 100 image indices (-1: missing) for tiles 1001..1100
    WrapMode wrap_s = WrapMode::kRepeat, wrap_t = WrapMode::kRepeat;
    RGBA scale{1.f, 1.f, 1.f, 1.f}, bias{0.f, 0.f, 0.f, 0.f}, fallback{0.f, 0.f, 0.f, 1.f};
    TextureOutput output = TextureOutput::kRGB;
    // UsdTransform2d on the st input: st' = R(rotation) (st * scale) + translation.
    float st_scale[2] = {1.f, 1.f};
    float st_rotation_degrees = 0.f;
    float st_translation[2] = {0.f, 0.f};
};

class TextureSet {
public:
    TextureSet() = default;
    // Validates (image sizes, texel counts, finite parameters, image indices in range) and
    // throws std::invalid_argument naming the problem. Decodes sRGB images in place.
    TextureSet(std::vector<Image> images, std::vector<TextureDesc> textures);

    size_t size() const { return textures_.size(); }
    bool empty() const { return textures_.empty(); }

    // The texture's output at st (scale and bias applied), as a colour: a scalar output is
    // replicated to three channels. Non-finite st gives the fallback.
    // A footprint filters: the texels under it are averaged, anisotropically (up to
    // kMaxAnisotropy trilinear probes along its longer axis, on the pyramid level of its
    // shorter one; 16 measured better than 8 on a plane to the horizon,
    // docs/benchmarks/textures.md). A footprint under one texel gives the point lookup's bilinear value.
    Color EvaluateColor(uint32_t texture, Vec2 st, const TextureFootprint& footprint = {}) const;
    float EvaluateFloat(uint32_t texture, Vec2 st, const TextureFootprint& footprint = {}) const;
    // All four channels after scale and bias (fallback where there is no data).
    RGBA EvaluateRGBA(uint32_t texture, Vec2 st, const TextureFootprint& footprint = {}) const;
    static constexpr int kMaxAnisotropy = 16;
    // Bytes of texels held: the images and their pyramids.
    size_t TexelBytes() const;
    // The texture's output averaged over its image(s) (every texel equally, scale and bias
    // applied): what light selection uses as a textured emitter's mean radiance.
    Color MeanColor(uint32_t texture) const;

    // Whether a texture emits nothing over a triangle: at every st inside the bounds of its
    // corners `st` (transform applied), each texel a bilinear lookup reads has an output
    // (scale and bias applied, the texture's output channels) of at most 0. False when it
    // cannot tell (non-finite st, a positive bias, a UDIM box across tiles). The test runs
    // on a grid of cells of up to 1024 per side, each "some texel positive": conservative,
    // never wrong. PrepareZeroTest(texture) first; ReleaseZeroTests() frees the grids.
    void PrepareZeroTest(uint32_t texture);
    bool ZeroOverTriangle(uint32_t texture, const Vec2 st[3]) const;
    void ReleaseZeroTests() { zero_grids_.clear(); }

private:
    // Per image of a prepared texture: a summed-area table of cells holding a positive texel.
    struct ZeroGrid {
        uint32_t cell = 1, cw = 0, ch = 0;
        std::vector<uint32_t> sat;  // (cw + 1) x (ch + 1)
        bool Any(int64_t x0, int64_t x1, int64_t y0, int64_t y1) const;  // texel ranges, inclusive
    };
    bool ZeroOverImage(const ZeroGrid& g, const Image& im, float s0, float s1, float t0, float t1, WrapMode ws,
                       WrapMode wt) const;
    struct Prepared {
        TextureDesc desc;
        float m[6];  // st' = (m0 s + m1 t + m4, m2 s + m3 t + m5)
        bool has_transform = false;
    };
    RGBA Bilinear(const Image& image, float s, float t, WrapMode ws, WrapMode wt) const;
    RGBA Filtered(int32_t image, float s, float t, Vec2 dx, Vec2 dy, WrapMode ws, WrapMode wt) const;
    RGBA Trilinear(int32_t image, float level, float s, float t, WrapMode ws, WrapMode wt) const;
    RGBA Texel(const Image& image, int64_t x, int64_t y) const;  // in range
    std::vector<Image> images_;
    // Per image, its levels 1, 2, ... (level 0 is the image): each half the size of the
    // one before (odd sizes round up), down to 1 x 1, texels box averages of the level before.
    std::vector<std::vector<Image>> pyramids_;
    std::vector<Prepared> textures_;
    std::map<std::pair<uint32_t, int32_t>, ZeroGrid> zero_grids_;  // (texture, image)
};

}  // namespace tessera
