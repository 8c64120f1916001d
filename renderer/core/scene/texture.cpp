#include "texture.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <stdexcept>
#include <string>

namespace tessera {

namespace {

bool AllFinite(const RGBA& v) {
    return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]) && std::isfinite(v[3]);
}

// Integer texel index under a wrap mode; -1 means "outside" (black mode only).
inline int64_t WrapIndex(int64_t i, int64_t n, WrapMode mode) {
    switch (mode) {
        case WrapMode::kRepeat:
            return ((i % n) + n) % n;
        case WrapMode::kClamp:
            return std::clamp<int64_t>(i, 0, n - 1);
        case WrapMode::kMirror: {
            int64_t k = ((i % (2 * n)) + 2 * n) % (2 * n);
            return k < n ? k : 2 * n - 1 - k;
        }
        case WrapMode::kBlack:
            return (i < 0 || i >= n) ? -1 : i;
    }
    return 0;
}

// Brings a coordinate into a small range before it is scaled to texels, so that huge st
// values never overflow the integer conversion. Each mode's result is unchanged by this:
// repeat has period 1, mirror period 2, and clamp/black see nothing beyond [0, 1].
inline float ReduceCoordinate(float s, WrapMode mode) {
    switch (mode) {
        case WrapMode::kRepeat:
            return s - std::floor(s);
        case WrapMode::kMirror:
            return s - 2.f * std::floor(0.5f * s);
        case WrapMode::kClamp:
        case WrapMode::kBlack:
            return std::clamp(s, -1.f, 2.f);
    }
    return s;
}

inline float Pick(const RGBA& v, TextureOutput out) {
    switch (out) {
        case TextureOutput::kR: return v[0];
        case TextureOutput::kG: return v[1];
        case TextureOutput::kB: return v[2];
        case TextureOutput::kA: return v[3];
        case TextureOutput::kRGB: return v[0];
    }
    return v[0];
}

inline Color ToColor(const RGBA& v, TextureOutput out) {
    if (out == TextureOutput::kRGB) return Color(v[0], v[1], v[2]);
    return Color(Pick(v, out));
}

// One axis of a level: n texels become ceil(n / 2), output texel j the box average of input
// [j r, (j + 1) r) with r = n / ceil(n / 2), partial texels weighed by their overlap. Even
// sizes are the plain 2-to-1 box; odd ones keep every texel's weight equal, so each level's
// mean is the image's (a checker's average stays exact at every level).
struct AxisWeights {
    std::vector<uint32_t> first;          // first input texel of output j
    std::vector<std::array<float, 3>> w;  // weights of inputs first, first + 1, first + 2
};

AxisWeights HalvingWeights(uint32_t n) {
    const uint32_t m = (n + 1) / 2;
    AxisWeights a;
    a.first.resize(m);
    a.w.resize(m);
    const double r = double(n) / double(m);
    for (uint32_t j = 0; j < m; ++j) {
        const double lo = j * r, hi = (j + 1) * r;
        a.first[j] = uint32_t(std::floor(lo));
        for (int k = 0; k < 3; ++k) {
            const double i0 = a.first[j] + k, i1 = i0 + 1.0;
            const double overlap = std::max(0.0, std::min(hi, i1) - std::max(lo, i0));
            a.w[j][k] = i0 < n ? float(overlap / r) : 0.f;
        }
    }
    return a;
}

Image HalfSize(const Image& in) {
    const uint32_t c = in.channels;
    const AxisWeights ax = HalvingWeights(in.width), ay = HalvingWeights(in.height);
    Image wide;  // halved along x only
    wide.width = uint32_t(ax.first.size());
    wide.height = in.height;
    wide.channels = c;
    wide.texels.assign(size_t(wide.width) * wide.height * c, 0.f);
    for (uint32_t y = 0; y < in.height; ++y)
        for (uint32_t x = 0; x < wide.width; ++x)
            for (int k = 0; k < 3; ++k) {
                const float w = ax.w[x][k];
                if (w == 0.f) continue;
                const float* src = &in.texels[(size_t(y) * in.width + ax.first[x] + k) * c];
                float* dst = &wide.texels[(size_t(y) * wide.width + x) * c];
                for (uint32_t q = 0; q < c; ++q) dst[q] += w * src[q];
            }
    Image out;
    out.width = wide.width;
    out.height = uint32_t(ay.first.size());
    out.channels = c;
    out.texels.assign(size_t(out.width) * out.height * c, 0.f);
    for (uint32_t y = 0; y < out.height; ++y)
        for (int k = 0; k < 3; ++k) {
            const float w = ay.w[y][k];
            if (w == 0.f) continue;
            const float* src = &wide.texels[size_t(ay.first[y] + k) * wide.width * c];
            float* dst = &out.texels[size_t(y) * out.width * c];
            for (size_t q = 0; q < size_t(out.width) * c; ++q) dst[q] += w * src[q];
        }
    return out;
}

}  // namespace

float SrgbToLinear(float c) {
    if (!(c > 0.f)) return 0.f;
    if (c <= 0.04045f) return c / 12.92f;
    return std::pow((c + 0.055f) / 1.055f, 2.4f);
}

TextureSet::TextureSet(std::vector<Image> images, std::vector<TextureDesc> textures) : images_(std::move(images)) {
    for (size_t i = 0; i < images_.size(); ++i) {
        Image& im = images_[i];
        const std::string name = "texture image " + std::to_string(i);
        if (im.width == 0 || im.height == 0 || im.channels < 1 || im.channels > 4)
            throw std::invalid_argument(name + ": needs a positive size and 1 to 4 channels");
        if (im.texels.size() != size_t(im.width) * im.height * im.channels)
            throw std::invalid_argument(name + ": holds " + std::to_string(im.texels.size()) + " values, not " +
                                        "width * height * channels");
        // Non-finite texels (corrupt float images) would poison every pixel that sees them.
        for (float& v : im.texels)
            if (!std::isfinite(v)) v = 0.f;
        if (im.srgb) {
            const uint32_t colour = im.channels == 2 ? 1 : std::min<uint32_t>(im.channels, 3);
            for (size_t k = 0; k < im.texels.size(); k += im.channels)
                for (uint32_t c = 0; c < colour; ++c) im.texels[k + c] = SrgbToLinear(im.texels[k + c]);
            im.srgb = false;  // decoded
        }
    }
    pyramids_.resize(images_.size());
    for (size_t i = 0; i < images_.size(); ++i) {
        const Image* finer = &images_[i];
        while (finer->width > 1 || finer->height > 1) {
            pyramids_[i].push_back(HalfSize(*finer));
            finer = &pyramids_[i].back();
        }
    }
    auto check_image = [&](int32_t index, size_t t) {
        if (index < -1 || index >= int64_t(images_.size()))
            throw std::invalid_argument("texture " + std::to_string(t) + " refers to image " + std::to_string(index) +
                                        " of " + std::to_string(images_.size()));
    };
    textures_.reserve(textures.size());
    for (size_t t = 0; t < textures.size(); ++t) {
        Prepared p;
        p.desc = std::move(textures[t]);
        const TextureDesc& d = p.desc;
        check_image(d.image, t);
        if (!d.udim_tiles.empty() && d.udim_tiles.size() != 100)
            throw std::invalid_argument("texture " + std::to_string(t) + ": udim_tiles must hold 100 entries");
        for (int32_t tile : d.udim_tiles) check_image(tile, t);
        if (!AllFinite(d.scale) || !AllFinite(d.bias) || !AllFinite(d.fallback) || !std::isfinite(d.st_scale[0]) ||
            !std::isfinite(d.st_scale[1]) || !std::isfinite(d.st_rotation_degrees) ||
            !std::isfinite(d.st_translation[0]) || !std::isfinite(d.st_translation[1]))
            throw std::invalid_argument("texture " + std::to_string(t) + " has a non-finite parameter");
        const float rad = d.st_rotation_degrees * (kPi / 180.f);
        const float c = std::cos(rad), s = std::sin(rad);
        p.m[0] = c * d.st_scale[0];
        p.m[1] = -s * d.st_scale[1];
        p.m[2] = s * d.st_scale[0];
        p.m[3] = c * d.st_scale[1];
        p.m[4] = d.st_translation[0];
        p.m[5] = d.st_translation[1];
        p.has_transform = !(p.m[0] == 1.f && p.m[1] == 0.f && p.m[2] == 0.f && p.m[3] == 1.f && p.m[4] == 0.f &&
                            p.m[5] == 0.f);
        textures_.push_back(std::move(p));
    }
}

RGBA TextureSet::Texel(const Image& im, int64_t x, int64_t y) const {
    const float* p = &im.texels[(size_t(y) * im.width + size_t(x)) * im.channels];
    switch (im.channels) {
        case 1: return {p[0], p[0], p[0], 1.f};
        case 2: return {p[0], p[0], p[0], p[1]};
        case 3: return {p[0], p[1], p[2], 1.f};
        default: return {p[0], p[1], p[2], p[3]};
    }
}

RGBA TextureSet::Bilinear(const Image& im, float s, float t, WrapMode ws, WrapMode wt) const {
    s = ReduceCoordinate(s, ws);
    t = ReduceCoordinate(t, wt);
    // Texel centres at half-integers; image rows run top to bottom while t runs upward.
    const float x = s * float(im.width) - 0.5f, y = (1.f - t) * float(im.height) - 0.5f;
    const float fx0 = std::floor(x), fy0 = std::floor(y);
    const float ax = x - fx0, ay = y - fy0;
    const int64_t x0 = int64_t(fx0), y0 = int64_t(fy0);
    const int64_t xs[2] = {WrapIndex(x0, im.width, ws), WrapIndex(x0 + 1, im.width, ws)};
    const int64_t ys[2] = {WrapIndex(y0, im.height, wt), WrapIndex(y0 + 1, im.height, wt)};
    const float wx[2] = {1.f - ax, ax}, wy[2] = {1.f - ay, ay};
    RGBA out{0.f, 0.f, 0.f, 0.f};
    for (int j = 0; j < 2; ++j) {
        if (ys[j] < 0) continue;  // black border
        for (int i = 0; i < 2; ++i) {
            if (xs[i] < 0) continue;
            const float w = wx[i] * wy[j];
            if (w == 0.f) continue;
            const RGBA v = Texel(im, xs[i], ys[j]);
            for (int c = 0; c < 4; ++c) out[c] += w * v[c];
        }
    }
    return out;
}

RGBA TextureSet::Trilinear(int32_t image, float level, float s, float t, WrapMode ws, WrapMode wt) const {
    const std::vector<Image>& pyramid = pyramids_[image];
    const float clamped = std::clamp(level, 0.f, float(pyramid.size()));
    const size_t l0 = size_t(clamped);
    const float f = clamped - float(l0);
    const Image& fine = l0 == 0 ? images_[image] : pyramid[l0 - 1];
    const RGBA a = Bilinear(fine, s, t, ws, wt);
    if (f == 0.f || l0 >= pyramid.size()) return a;
    const RGBA b = Bilinear(pyramid[l0], s, t, ws, wt);
    RGBA out;
    for (int c = 0; c < 4; ++c) out[c] = a[c] + f * (b[c] - a[c]);
    return out;
}

RGBA TextureSet::Filtered(int32_t image, float s, float t, Vec2 dx, Vec2 dy, WrapMode ws, WrapMode wt) const {
    const Image& im = images_[image];
    const float w = float(im.width), h = float(im.height);
    // The footprint's axes in finest-level texels.
    const auto sq = [](float x) { return x * x; };
    const float la = sq(dx.x * w) + sq(dx.y * h), lb = sq(dy.x * w) + sq(dy.y * h);
    const float major = std::sqrt(std::max(la, lb));
    if (!(major > 1.f) || !std::isfinite(major)) return Bilinear(im, s, t, ws, wt);
    const Vec2 axis = la >= lb ? dx : dy;
    // The shorter axis picks the level; a thin footprint is covered by probes along the
    // longer one, at most kMaxAnisotropy of them (beyond that the level rises: blur rather
    // than alias).
    const float minor = std::max(std::sqrt(std::min(la, lb)), major / float(kMaxAnisotropy));
    const int probes = std::clamp(int(std::ceil(major / minor - 1e-3f)), 1, kMaxAnisotropy);
    const float level = std::log2(std::max(minor, 1.f));
    RGBA sum{0.f, 0.f, 0.f, 0.f};
    for (int k = 0; k < probes; ++k) {
        const float f = (float(k) + 0.5f) / float(probes) - 0.5f;
        const RGBA v = Trilinear(image, level, s + f * axis.x, t + f * axis.y, ws, wt);
        for (int c = 0; c < 4; ++c) sum[c] += v[c];
    }
    for (int c = 0; c < 4; ++c) sum[c] /= float(probes);
    return sum;
}

size_t TextureSet::TexelBytes() const {
    size_t n = 0;
    for (size_t i = 0; i < images_.size(); ++i) {
        n += images_[i].texels.size();
        for (const Image& level : pyramids_[i]) n += level.texels.size();
    }
    return n * sizeof(float);
}

RGBA TextureSet::EvaluateRGBA(uint32_t texture, Vec2 st, const TextureFootprint& footprint) const {
    const Prepared& p = textures_[texture];
    const TextureDesc& d = p.desc;
    if (!std::isfinite(st.x) || !std::isfinite(st.y)) return d.fallback;
    float s = st.x, t = st.y;
    Vec2 dx = footprint.dx, dy = footprint.dy;
    if (p.has_transform) {
        s = p.m[0] * st.x + p.m[1] * st.y + p.m[4];
        t = p.m[2] * st.x + p.m[3] * st.y + p.m[5];
        if (!std::isfinite(s) || !std::isfinite(t)) return d.fallback;
        dx = {p.m[0] * footprint.dx.x + p.m[1] * footprint.dx.y, p.m[2] * footprint.dx.x + p.m[3] * footprint.dx.y};
        dy = {p.m[0] * footprint.dy.x + p.m[1] * footprint.dy.y, p.m[2] * footprint.dy.x + p.m[3] * footprint.dy.y};
    }
    const bool point = dx.x == 0.f && dx.y == 0.f && dy.x == 0.f && dy.y == 0.f;
    RGBA v;
    if (!d.udim_tiles.empty()) {
        // UDIM: tile 1001 + u + 10 v covers [u, u+1) x [v, v+1); filtering stays in the tile.
        const float fu = std::floor(s), fv = std::floor(t);
        if (fu < 0.f || fu > 9.f || fv < 0.f || fv > 9.f) return d.fallback;
        const int32_t image = d.udim_tiles[size_t(fv) * 10 + size_t(fu)];
        if (image < 0) return d.fallback;
        v = point ? Bilinear(images_[image], s - fu, t - fv, WrapMode::kClamp, WrapMode::kClamp)
                  : Filtered(image, s - fu, t - fv, dx, dy, WrapMode::kClamp, WrapMode::kClamp);
    } else {
        if (d.image < 0) return d.fallback;
        v = point ? Bilinear(images_[d.image], s, t, d.wrap_s, d.wrap_t)
                  : Filtered(d.image, s, t, dx, dy, d.wrap_s, d.wrap_t);
    }
    for (int c = 0; c < 4; ++c) v[c] = v[c] * d.scale[c] + d.bias[c];
    return v;
}

Color TextureSet::EvaluateColor(uint32_t texture, Vec2 st, const TextureFootprint& footprint) const {
    return ToColor(EvaluateRGBA(texture, st, footprint), textures_[texture].desc.output);
}

float TextureSet::EvaluateFloat(uint32_t texture, Vec2 st, const TextureFootprint& footprint) const {
    return Pick(EvaluateRGBA(texture, st, footprint), textures_[texture].desc.output);
}

Color TextureSet::MeanColor(uint32_t texture) const {
    const TextureDesc& d = textures_[texture].desc;
    std::vector<int32_t> used;
    if (!d.udim_tiles.empty()) {
        for (int32_t i : d.udim_tiles)
            if (i >= 0) used.push_back(i);
    } else if (d.image >= 0) {
        used.push_back(d.image);
    }
    if (used.empty()) return ToColor(d.fallback, d.output);
    // Negative outputs (scale/bias can produce them) emit nothing, so they do not cancel
    // positive texels here either.
    double sum[4] = {0, 0, 0, 0};
    size_t count = 0;
    for (int32_t i : used) {
        const Image& im = images_[i];
        for (uint32_t y = 0; y < im.height; ++y)
            for (uint32_t x = 0; x < im.width; ++x) {
                const RGBA v = Texel(im, x, y);
                for (int c = 0; c < 4; ++c) sum[c] += std::max(0.f, v[c] * d.scale[c] + d.bias[c]);
            }
        count += size_t(im.width) * im.height;
    }
    RGBA mean;
    for (int c = 0; c < 4; ++c) mean[c] = float(sum[c] / double(count));
    return ToColor(mean, d.output);
}

namespace {

// The texel indices [i0, i1] of one axis as read under a wrap mode: up to two ranges in
// [0, n - 1] (count 0: nothing read, i.e. all outside a black border).
struct AxisRanges {
    int count = 0;
    int64_t lo[2], hi[2];
};

int64_t FloorMod(int64_t i, int64_t n) { return ((i % n) + n) % n; }

AxisRanges WrapRanges(int64_t i0, int64_t i1, int64_t n, WrapMode mode) {
    AxisRanges r;
    auto one = [&](int64_t a, int64_t b) {
        r.lo[r.count] = a;
        r.hi[r.count] = b;
        ++r.count;
    };
    if (mode == WrapMode::kClamp) {
        one(std::clamp<int64_t>(i0, 0, n - 1), std::clamp<int64_t>(i1, 0, n - 1));
    } else if (mode == WrapMode::kBlack) {
        if (i1 >= 0 && i0 <= n - 1) one(std::max<int64_t>(i0, 0), std::min<int64_t>(i1, n - 1));
    } else if (i1 - i0 + 1 >= n) {
        one(0, n - 1);
    } else if (mode == WrapMode::kRepeat) {
        const int64_t a = FloorMod(i0, n), b = FloorMod(i1, n);
        if (a <= b) {
            one(a, b);
        } else {
            one(a, n - 1);
            one(0, b);
        }
    } else {  // mirror: cut where the reflection turns (multiples of n); each piece is a run
        const int64_t cut = (i0 >= 0 ? i0 / n + 1 : -((-i0 - 1) / n)) * n;  // first multiple of n above i0
        auto piece = [&](int64_t a, int64_t b) {
            const int64_t wa = WrapIndex(a, n, mode), wb = WrapIndex(b, n, mode);
            one(std::min(wa, wb), std::max(wa, wb));
        };
        if (cut > i1) {
            piece(i0, i1);
        } else {  // shorter than n: at most one cut
            piece(i0, cut - 1);
            piece(cut, i1);
        }
    }
    return r;
}

}  // namespace

bool TextureSet::ZeroGrid::Any(int64_t x0, int64_t x1, int64_t y0, int64_t y1) const {
    const int64_t cx0 = x0 / cell, cx1 = x1 / cell + 1, cy0 = y0 / cell, cy1 = y1 / cell + 1;
    const auto at = [&](int64_t x, int64_t y) { return int64_t(sat[size_t(y) * (cw + 1) + size_t(x)]); };
    return at(cx1, cy1) - at(cx0, cy1) - at(cx1, cy0) + at(cx0, cy0) > 0;
}

void TextureSet::PrepareZeroTest(uint32_t texture) {
    const TextureDesc& d = textures_[texture].desc;
    std::vector<int32_t> used = d.udim_tiles;
    if (used.empty()) used.push_back(d.image);
    const int channels[2] = {d.output == TextureOutput::kRGB ? 0 : int(d.output),
                             d.output == TextureOutput::kRGB ? 2 : int(d.output)};
    for (int32_t i : used) {
        if (i < 0 || zero_grids_.count({texture, i})) continue;
        const Image& im = images_[i];
        ZeroGrid g;
        g.cell = std::max<uint32_t>(1, (std::max(im.width, im.height) + 1023) / 1024);
        g.cw = (im.width + g.cell - 1) / g.cell;
        g.ch = (im.height + g.cell - 1) / g.cell;
        std::vector<uint8_t> positive(size_t(g.cw) * g.ch, 0);
        for (uint32_t y = 0; y < im.height; ++y)
            for (uint32_t x = 0; x < im.width; ++x) {
                const RGBA v = Texel(im, x, y);
                bool any = false;
                for (int c = channels[0]; c <= channels[1]; ++c) any = any || v[c] * d.scale[c] + d.bias[c] > 0.f;
                if (any) positive[size_t(y / g.cell) * g.cw + x / g.cell] = 1;
            }
        g.sat.assign(size_t(g.cw + 1) * (g.ch + 1), 0);
        for (uint32_t y = 0; y < g.ch; ++y)
            for (uint32_t x = 0; x < g.cw; ++x)
                g.sat[size_t(y + 1) * (g.cw + 1) + x + 1] = positive[size_t(y) * g.cw + x] +
                                                              g.sat[size_t(y) * (g.cw + 1) + x + 1] +
                                                              g.sat[size_t(y + 1) * (g.cw + 1) + x] -
                                                              g.sat[size_t(y) * (g.cw + 1) + x];
        zero_grids_.emplace(std::make_pair(texture, i), std::move(g));
    }
}

bool TextureSet::ZeroOverImage(const ZeroGrid& g, const Image& im, float s0, float s1, float t0, float t1,
                               WrapMode ws, WrapMode wt) const {
    // Texel centres at half-integers, rows top to bottom (Bilinear): a lookup at x reads
    // floor(x) and floor(x) + 1.
    // Widened by a margin for float rounding: lookups interpolate st and scale it to
    // texels in float, which may land a hair outside the corners' box.
    const double w = im.width, h = im.height;
    const double mx = 0.01 + 1e-6 * w * std::max(std::abs(double(s0)), std::abs(double(s1)));
    const double my = 0.01 + 1e-6 * h * std::max(std::abs(double(t0)), std::abs(double(t1)));
    const int64_t x0 = int64_t(std::floor(double(s0) * w - 0.5 - mx));
    const int64_t x1 = int64_t(std::floor(double(s1) * w - 0.5 + mx)) + 1;
    const int64_t y0 = int64_t(std::floor((1.0 - double(t1)) * h - 0.5 - my));
    const int64_t y1 = int64_t(std::floor((1.0 - double(t0)) * h - 0.5 + my)) + 1;
    const AxisRanges xs = WrapRanges(x0, x1, im.width, ws), ys = WrapRanges(y0, y1, im.height, wt);
    for (int i = 0; i < xs.count; ++i)
        for (int j = 0; j < ys.count; ++j)
            if (g.Any(xs.lo[i], xs.hi[i], ys.lo[j], ys.hi[j])) return false;
    return true;
}

bool TextureSet::ZeroOverTriangle(uint32_t texture, const Vec2 st[3]) const {
    const Prepared& p = textures_[texture];
    const TextureDesc& d = p.desc;
    const int c0 = d.output == TextureOutput::kRGB ? 0 : int(d.output), c1 = d.output == TextureOutput::kRGB ? 2 : c0;
    // A positive bias lifts texels and the black border alike; a black border's missing
    // weight leaves bias x (1 - weights), at most 0 only when the bias is.
    for (int c = c0; c <= c1; ++c)
        if (d.bias[c] > 0.f) return false;
    float s0 = INFINITY, s1 = -INFINITY, t0 = INFINITY, t1 = -INFINITY;
    for (int k = 0; k < 3; ++k) {
        float s = st[k].x, t = st[k].y;
        if (p.has_transform) {
            s = p.m[0] * st[k].x + p.m[1] * st[k].y + p.m[4];
            t = p.m[2] * st[k].x + p.m[3] * st[k].y + p.m[5];
        }
        if (!std::isfinite(s) || !std::isfinite(t) || std::abs(s) > 1e4f || std::abs(t) > 1e4f) return false;
        s0 = std::min(s0, s), s1 = std::max(s1, s), t0 = std::min(t0, t), t1 = std::max(t1, t);
    }
    int32_t image = d.image;
    WrapMode ws = d.wrap_s, wt = d.wrap_t;
    if (!d.udim_tiles.empty()) {
        const float fu = std::floor(s0), fv = std::floor(t0);
        // Within one tile by a margin: a lookup's rounding must not carry it to the next.
        const float e = 1e-5f;
        if (fu != std::floor(s1) || fv != std::floor(t1) || fu < 0.f || fu > 9.f || fv < 0.f || fv > 9.f ||
            s0 - fu < e || fu + 1.f - s1 < e || t0 - fv < e || fv + 1.f - t1 < e)
            return false;
        image = d.udim_tiles[size_t(fv) * 10 + size_t(fu)];
        s0 -= fu, s1 -= fu, t0 -= fv, t1 -= fv;
        ws = wt = WrapMode::kClamp;
    }
    if (image < 0) return false;  // the fallback: a constant the caller weighs
    const auto it = zero_grids_.find({texture, image});
    if (it == zero_grids_.end()) return false;
    return ZeroOverImage(it->second, images_[image], s0, s1, t0, t1, ws, wt);
}

}  // namespace tessera
