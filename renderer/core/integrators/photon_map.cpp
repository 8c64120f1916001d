#include "photon_map.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <stdexcept>

#include "bsdf.h"
#include "integrator.h"
#include "sampler.h"
#include "sampling.h"

namespace tessera {

namespace {

// Photon streams use the sampler's pixel index above every image's (2^40 pixels), so they
// are independent of every camera sample's stream.
constexpr uint32_t kPhotonStream = 3;
// Paths per work item: each item fills its own vector, concatenated in item order.
constexpr uint32_t kPathsPerChunk = 4096;

uint16_t ToHalf(float x) {
    const _Float16 h = static_cast<_Float16>(x);
    uint16_t bits;
    std::memcpy(&bits, &h, 2);
    return bits;
}
float FromHalf(uint16_t bits) {
    _Float16 h;
    std::memcpy(&h, &bits, 2);
    return static_cast<float>(h);
}

// Octahedral map of the unit sphere onto [-1, 1]^2, quantised to 16 bits a coordinate
// (an angular error below 1e-4 rad, far under any kernel's extent).
std::array<uint16_t, 2> EncodeDirection(Vec3 v) {
    const float l1 = std::abs(v.x) + std::abs(v.y) + std::abs(v.z);
    float x = v.x / l1, y = v.y / l1;
    if (v.z < 0.f) {
        const float ox = (1.f - std::abs(y)) * (x >= 0.f ? 1.f : -1.f);
        const float oy = (1.f - std::abs(x)) * (y >= 0.f ? 1.f : -1.f);
        x = ox;
        y = oy;
    }
    auto q = [](float c) { return uint16_t(std::lround((std::clamp(c, -1.f, 1.f) * 0.5f + 0.5f) * 65535.f)); };
    return {q(x), q(y)};
}
Vec3 DecodeDirection(std::array<uint16_t, 2> e) {
    float x = float(e[0]) / 65535.f * 2.f - 1.f, y = float(e[1]) / 65535.f * 2.f - 1.f;
    const float z = 1.f - std::abs(x) - std::abs(y);
    if (z < 0.f) {
        const float ox = (1.f - std::abs(y)) * (x >= 0.f ? 1.f : -1.f);
        const float oy = (1.f - std::abs(x)) * (y >= 0.f ? 1.f : -1.f);
        x = ox;
        y = oy;
    }
    return Normalize(Vec3(x, y, z));
}

template <typename T>
void Append(std::string* out, const T* data, size_t count) {
    if (count) out->append(reinterpret_cast<const char*>(data), count * sizeof(T));
}
template <typename T>
void Read(std::string_view data, size_t* offset, T* dst, size_t count, std::string_view who) {
    const size_t bytes = count * sizeof(T);
    if (data.size() < *offset || data.size() - *offset < bytes)
        throw std::invalid_argument(std::string(who) + ": the scene product is truncated");
    if (bytes) std::memcpy(dst, data.data() + *offset, bytes);
    *offset += bytes;
}

// Jensen's projection maps as a one-sample mixture: with probability `aim` the photon
// leaves in a direction drawn uniformly from the cone that the delta surfaces' bounding
// sphere subtends at es->p, else in the light's own direction; its throughput is then
// Le |cos| / (pdf_pos ((1 - aim) pdf_light + aim pdf_cone)), so the map's expectation is
// unchanged. A caustic-only map may aim every photon (aim = 1): each of its paths starts
// L S and so crosses the sphere. False: the photon carries nothing.
bool AimEmission(const Scene& scene, uint32_t light, float aim, float u_aim, Vec2 u_dir, EmissionSample* es) {
    const float r = scene.delta_surfaces_radius();
    if (es->infinite || !(r > 0.f)) return true;
    const Vec3 to_center = scene.delta_surfaces_center() - es->p;
    const float d2 = LengthSquared(to_center);
    if (d2 <= r * r) return true;  // inside the bound every direction may meet a delta surface
    const float sin2_max = r * r / d2, one_minus_cos = ConeOneMinusCos(sin2_max);
    const Frame cone = Frame::FromZ(to_center / std::sqrt(d2));
    const Vec3 w = u_aim < aim ? Normalize(cone.FromLocal(SampleUniformCone(u_dir, one_minus_cos))) : es->wo;
    Color Le_cos;
    float pdf_light = 0.f;
    if (!scene.EmissionToward(light, *es, w, &Le_cos, &pdf_light)) return true;
    // In the cone, by its sine (exact for small cones), with a margin for the sampled
    // direction's rounding: a band of relative width 1e-3 at the cone's rim.
    const float cos_axis = Dot(w, cone.n);
    const bool in_cone = cos_axis > 0.f && LengthSquared(Cross(w, cone.n)) <= sin2_max * (1.f + 1e-3f);
    const float pdf = (1.f - aim) * pdf_light + (in_cone ? aim / (2.f * kPi * one_minus_cos) : 0.f);
    if (!(pdf > 0.f) || IsBlack(Le_cos)) return false;
    es->wo = w;
    es->beta = Le_cos / (es->pdf_pos * pdf);
    return true;
}

}  // namespace

std::vector<StoredPhoton> TracePhotons(const Scene& scene, uint32_t seed, uint64_t stream, uint32_t paths,
                                       int max_depth, const PhotonFilter& filter, ShutterSlices slices, int threads,
                                       float specular_aim) {
    const LightSampler& lights = scene.light_sampler();
    const bool aiming = specular_aim > 0.f && scene.delta_surfaces_radius() > 0.f;
    if (lights.empty() || paths == 0) return {};
    // 1 / n_b per slice (a still scene's one slice: 1 / paths).
    std::vector<float> inv_slice_paths(slices.count);
    for (uint32_t b = 0; b < slices.count; ++b) inv_slice_paths[b] = 1.f / float(std::max(1u, slices.Paths(paths, b)));
    const uint32_t chunks = (paths + kPathsPerChunk - 1) / kPathsPerChunk;
    std::vector<std::vector<StoredPhoton>> kept(chunks);
    auto trace_path = [&](uint32_t i, std::vector<StoredPhoton>& out) {
        PixelSampler sampler(seed, stream, i, kPhotonStream);
        const uint8_t slice = uint8_t(slices.SliceOfPath(i));
        const ShutterTimeScope instant(slices.Instant(i, LightPathInstant(scene, sampler)));
        float pmf = 0.f;
        const uint32_t light = lights.Sample(sampler.Get1D(), &pmf);
        const Vec2 u_pos = sampler.Get2D(), u_dir = sampler.Get2D();
        const float u_side = sampler.Get1D();
        EmissionSample es;
        if (!scene.SampleEmission(light, u_pos, u_dir, u_side, &es) || !(pmf > 0.f)) return;
        if (aiming && !AimEmission(scene, light, specular_aim, sampler.Get1D(), u_dir, &es)) return;
        Color beta = es.beta * (inv_slice_paths[slice] / pmf);
        Ray ray{es.on_surface ? OffsetRayOrigin(es.p, es.p_error, es.n, es.wo) : es.p, es.wo};
        bool all_specular = true;
        for (int bounces = 0; bounces <= max_depth; ++bounces) {
            SurfaceHit hit;
            if (!scene.Intersect(ray, &hit)) return;
            const BSDF bsdf = scene.BSDFAt(hit, TransportMode::Importance);
            if (bsdf.Flags() == kBSDFUnset) return;
            const Vec3 wo = -ray.d;
            if (bsdf.IsNonSpecular()) {
                if (bounces >= filter.min_bounces && (!filter.caustic_only || (bounces > 0 && all_specular)))
                    out.push_back({hit.p, wo, beta, 0.f, slice});
                if (filter.caustic_only) return;
            }
            if (bounces == max_depth) return;
            const Frame frame = Frame::FromZ(hit.ns);
            const Vec3 wo_local = frame.ToLocal(wo);
            const float uc = sampler.Get1D();
            const std::optional<BSDFSample> bs = bsdf.Sample_f(wo_local, uc, sampler.Get2D());
            if (!bs || !(bs->pdf > 0.f) || IsBlack(bs->f)) return;
            const Vec3 wi = Normalize(frame.FromLocal(bs->wi));
            if (!SidesAgree(wo, wi, hit.ng, wo_local, bs->wi)) return;
            if (!bs->is_specular) {
                if (filter.caustic_only) return;
                all_specular = false;
            }
            const Color scatter =
                bs->f * (std::abs(bs->wi.z) / bs->pdf * ImportanceShadingCorrection(wo, wi, hit.ns, hit.ng));
            // Russian roulette on the scattering's albedo (after the first bounce), so a
            // photon keeps roughly the power it had: a map of even powers estimates best.
            const Color next = beta * scatter;
            if (bounces >= 1) {
                const float q = std::min(1.f, MaxComponent(next) / std::max(MaxComponent(beta), 1e-30f));
                if (sampler.Get1D() >= q) return;
                beta = next / q;
            } else {
                beta = next;
            }
            ray = {OffsetRayOrigin(hit.p, hit.p_error, hit.ng, wi), wi};
        }
    };
    tbb::task_arena arena(threads > 0 ? threads : tbb::this_task_arena::max_concurrency());
    arena.execute([&] {
        tbb::parallel_for(tbb::blocked_range<uint32_t>(0, chunks, 1), [&](const tbb::blocked_range<uint32_t>& r) {
            for (uint32_t c = r.begin(); c != r.end(); ++c) {
                const uint32_t end = std::min(paths, (c + 1) * kPathsPerChunk);
                for (uint32_t i = c * kPathsPerChunk; i < end; ++i) trace_path(i, kept[c]);
            }
        });
    });
    std::vector<StoredPhoton> all;
    size_t total = 0;
    for (const auto& k : kept) total += k.size();
    all.reserve(total);
    for (const auto& k : kept) all.insert(all.end(), k.begin(), k.end());
    return all;
}

void PhotonGrid::Serialize(const std::vector<StoredPhoton>& photons, float cell, ShutterSlices slices,
                           std::string* out) {
    const uint32_t count = uint32_t(photons.size());
    uint32_t buckets = 1;
    while (buckets < count) buckets <<= 1;
    float scale = 0.f;
    for (const StoredPhoton& ph : photons) scale = std::max(scale, MaxComponent(ph.power));
    std::vector<uint32_t> start(buckets + 1, 0), bucket_of(count);
    auto cell_of = [cell](float x) { return int(std::floor(x / cell)); };
    for (uint32_t i = 0; i < count; ++i) {
        const Vec3 p = photons[i].p;
        bucket_of[i] = HashGridBucket(cell_of(p.x), cell_of(p.y), cell_of(p.z), photons[i].time_slice, buckets);
        ++start[bucket_of[i] + 1];
    }
    for (uint32_t b = 0; b < buckets; ++b) start[b + 1] += start[b];
    std::vector<float> pos(3 * size_t(count)), radius(count);
    std::vector<std::array<uint16_t, 2>> dir(count);
    std::vector<std::array<uint16_t, 3>> power(count);
    std::vector<uint8_t> slice(count);
    std::vector<uint32_t> fill(start.begin(), start.end() - 1);
    const float inv_scale = scale > 0.f ? 1.f / scale : 0.f;
    for (uint32_t i = 0; i < count; ++i) {
        const uint32_t k = fill[bucket_of[i]]++;
        const StoredPhoton& ph = photons[i];
        pos[3 * k] = ph.p.x, pos[3 * k + 1] = ph.p.y, pos[3 * k + 2] = ph.p.z;
        radius[k] = ph.radius;
        dir[k] = EncodeDirection(ph.wi);
        power[k] = {ToHalf(ph.power.x * inv_scale), ToHalf(ph.power.y * inv_scale), ToHalf(ph.power.z * inv_scale)};
        slice[k] = ph.time_slice;
    }
    const uint32_t head[3] = {count, buckets, slices.count};
    const float fhead[2] = {cell, scale};
    Append(out, head, 3);
    Append(out, fhead, 2);
    Append(out, start.data(), start.size());
    Append(out, pos.data(), pos.size());
    Append(out, radius.data(), radius.size());
    Append(out, dir.data(), dir.size());
    Append(out, power.data(), power.size());
    Append(out, slice.data(), slice.size());
}

void PhotonGrid::Parse(std::string_view data, size_t* offset, std::string_view who) {
    uint32_t head[3];
    float fhead[2];
    Read(data, offset, head, 3, who);
    Read(data, offset, fhead, 2, who);
    const uint32_t count = head[0], buckets = head[1], slices = head[2];
    // Bound the sizes by what the bytes can hold before allocating anything.
    if (buckets == 0 || (buckets & (buckets - 1)) != 0 || uint64_t(buckets) > data.size() ||
        uint64_t(count) * 27 > data.size() || slices < 1 || slices > kMaxShutterSlices || !(fhead[0] > 0.f) || !std::isfinite(fhead[0]) || !(fhead[1] >= 0.f))
        throw std::invalid_argument(std::string(who) + ": the scene product is not a photon map");
    cell_ = fhead[0];
    power_scale_ = fhead[1];
    buckets_ = buckets;
    slices_ = ShutterSlices{slices};
    start_.resize(size_t(buckets) + 1);
    Read(data, offset, start_.data(), start_.size(), who);
    if (start_.front() != 0 || start_.back() != count || !std::is_sorted(start_.begin(), start_.end()))
        throw std::invalid_argument(std::string(who) + ": the scene product's photon grid is inconsistent");
    pos_.resize(3 * size_t(count));
    radius_.resize(count);
    dir_.resize(count);
    power_.resize(count);
    slice_.resize(count);
    Read(data, offset, pos_.data(), pos_.size(), who);
    Read(data, offset, radius_.data(), radius_.size(), who);
    for (float r : radius_)
        if (!(r > 0.f && r <= cell_))
            throw std::invalid_argument(std::string(who) + ": the scene product has a photon radius beyond its grid");
    Read(data, offset, dir_.data(), dir_.size(), who);
    Read(data, offset, power_.data(), power_.size(), who);
    Read(data, offset, slice_.data(), slice_.size(), who);
    for (uint8_t b : slice_)
        if (b >= slices) throw std::invalid_argument(std::string(who) + ": the scene product has a photon beyond its time slices");
}

int PhotonGrid::CellOf(float x) const { return int(std::floor(x / cell_)); }
Vec3 PhotonGrid::Direction(uint32_t k) const { return DecodeDirection(dir_[k]); }
Color PhotonGrid::Power(uint32_t k) const {
    return Color(FromHalf(power_[k][0]), FromHalf(power_[k][1]), FromHalf(power_[k][2])) * power_scale_;
}

std::string PhotonProductBegin(std::string_view magic4, uint32_t iteration, uint32_t maps) {
    std::string out(magic4.substr(0, 4));
    const uint32_t head[2] = {iteration, maps};
    Append(&out, head, 2);
    return out;
}

uint32_t PhotonProductParse(std::string_view data, std::string_view magic4, uint32_t maps, size_t* offset,
                            std::string_view who) {
    if (data.size() < 12 || data.substr(0, 4) != magic4.substr(0, 4))
        throw std::invalid_argument(std::string(who) + ": the scene product is not this integrator's photon map");
    *offset = 4;
    uint32_t head[2];
    Read(data, offset, head, 2, who);
    if (head[1] != maps) throw std::invalid_argument(std::string(who) + ": the scene product has the wrong maps");
    return head[0];
}

}  // namespace tessera
