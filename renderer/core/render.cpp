#include "render.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <xmmintrin.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <limits>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>

#include "bsdf.h"
#include "integrator.h"
#include "ray_counters.h"
#include "sampler.h"
#include "splat_film.h"

namespace tessera {

namespace {

// Embree wants flush-to-zero and denormals-are-zero in every thread that traces rays.
// Restore the caller's mode afterwards: the thread may be Python's.
class ScopedFlushDenormals {
public:
    ScopedFlushDenormals() : saved_(_mm_getcsr()) { _mm_setcsr(saved_ | 0x8040u); }
    ~ScopedFlushDenormals() { _mm_setcsr(saved_); }

private:
    unsigned int saved_;
};

}  // namespace

namespace {

// One sample of the AOVs along a camera ray (definitions in render.h).
struct AOVSample {
    Color albedo;
    Vec3 normal;
    float depth = 0.f;
    bool hit = false;
};

AOVSample SampleAOVs(const Scene& scene, const Camera& camera, Ray ray, float t_min, float t_max, int max_depth,
                     PixelSampler& sampler) {
    AOVSample out;
    Color beta(1.f);
    for (int depth = 0; depth <= max_depth; ++depth) {
        SurfaceHit hit;
        if (!(depth == 0 ? scene.Intersect(ray, &hit, t_min, t_max) : scene.Intersect(ray, &hit))) break;
        const Vec3 wo = -ray.d;
        if (depth == 0) {
            out.hit = true;
            out.depth = Dot(hit.p - camera.origin, camera.forward);
            out.normal = Dot(hit.ng, wo) >= 0.f ? hit.ns : -hit.ns;
        }
        const BSDF bsdf = scene.BSDFAt(hit, TransportMode::Radiance);
        if (bsdf.Flags() == kBSDFUnset) break;
        const Frame frame = Frame::FromZ(hit.ns);
        const Vec3 wo_local = frame.ToLocal(wo);
        const float uc = sampler.Get1D();
        const std::optional<BSDFSample> bs = bsdf.Sample_f(wo_local, uc, sampler.Get2D());
        if (bsdf.IsNonSpecular()) {
            // f |cos| / pdf of one BSDF sample: an unbiased estimate of rho(wo).
            if (bs && bs->pdf > 0.f) out.albedo = beta * bs->f * (std::abs(bs->wi.z) / bs->pdf);
            break;
        }
        if (!bs || !(bs->pdf > 0.f) || IsBlack(bs->f)) break;
        const Vec3 wi = Normalize(frame.FromLocal(bs->wi));
        if (!SidesAgree(wo, wi, hit.ng, wo_local, bs->wi)) break;
        beta *= bs->f * (std::abs(bs->wi.z) / bs->pdf);
        // Without refraction's radiance scaling (1/eta^2 per crossing): the albedo seen
        // through one glass surface is its transmittance.
        if (bs->is_transmission) beta *= bs->eta * bs->eta;
        ray = {OffsetRayOrigin(hit.p, hit.p_error, hit.ng, wi), wi};
    }
    return out;
}

// TESSERA_TEXTURE_FILTER=point turns texture filtering off (point lookups on the finest
// level, as before filtering existed): a diagnostic for comparing images. Every worker of a
// farm job must agree on it.
bool TextureFilteringOn() {
    static const bool on = [] {
        const char* v = std::getenv("TESSERA_TEXTURE_FILTER");
        return !(v && std::string(v) == "point");
    }();
    return on;
}

TextureFootprintCamera FootprintCameraOf(const Camera& camera) {
    TextureFootprintCamera c;
    c.origin = camera.origin;
    c.forward = camera.forward;
    c.orthographic = camera.IsOrthographic();
    // The window is 2 tan_half_height tall at distance 1 (perspective) or in scene units
    // (orthographic): a fraction of one pixel's share of it, at the image centre.
    const float pixel = kFootprintPixelFraction * 2.f * camera.tan_half_height / float(camera.height);
    c.pixel_angle = c.orthographic ? 0.f : pixel;
    c.pixel_width = c.orthographic ? pixel : 0.f;
    return c;
}

}  // namespace

RenderStats RenderTile(const Scene& scene, const Camera& camera, const RenderOptions& options, TileRect tile,
                       float* rgba, float* variance, int64_t* splats, const AOVBuffers& aovs,
                       const VarianceBatches& batches) {
    if (tile.width == 0 || tile.height == 0) return {};
    if (uint64_t(tile.x0) + tile.width > camera.width || uint64_t(tile.y0) + tile.height > camera.height)
        throw std::invalid_argument("tile lies outside the image");
    if (options.spp == 0) throw std::invalid_argument("spp must be at least 1");
    if (uint64_t(options.sample_start) + options.spp > 0xFFFFFFFFull)
        throw std::invalid_argument("sample indices must stay below 2^32");
    if (options.max_depth < 0) throw std::invalid_argument("max_depth must be >= 0");
    const std::optional<TileRect>& window = options.camera_window;
    if (window && (window->width == 0 || window->height == 0 || uint64_t(window->x0) + window->width > camera.width ||
                   uint64_t(window->y0) + window->height > camera.height))
        throw std::invalid_argument("the camera window must be a non-empty region inside the image");
    if (!kFullFeatures && (camera.HasLens() || camera.Moves() || aovs.any()))
        throw std::invalid_argument("this renderer build (TESSERA_LAMBERT_ONLY) renders through a still pinhole "
                                    "camera and without AOVs only");

    const std::unique_ptr<Integrator> integrator =
        Integrator::Create(options.integrator, {options.max_depth, options.integrator_params, options.scene_product},
                           scene);
    const IntegratorInfo& info = integrator->info();
    if (info.scene_passes && options.scene_product.empty())
        throw std::invalid_argument("integrator '" + options.integrator +
                                    "' renders tiles from its scene pass's product, and none was given");
    if (batches.count && !info.splats)
        throw std::invalid_argument("variance batches are for integrators that splat; '" + options.integrator +
                                    "' does not");
    if (batches.count && (batches.count > options.spp || !batches.splats || !batches.rgb))
        throw std::invalid_argument("variance batches need 1 to spp batches and their splat and rgb buffers");
    if (info.splats && !splats)
        throw std::invalid_argument("integrator '" + options.integrator +
                                    "' splats across tiles and needs a full-frame splat buffer");
    SplatFilm film(splats, camera.width, camera.height, scene.splat_exponent());
    std::vector<SplatFilm> batch_films;  // each adds to `splats` and to its batch's buffer
    for (uint32_t b = 0; b < batches.count; ++b)
        batch_films.emplace_back(splats, camera.width, camera.height, scene.splat_exponent(),
                                 batches.splats + size_t(b) * camera.width * camera.height * 3);
    if (window) {
        film.KeepOnly(window->x0, window->y0, window->width, window->height);
        for (SplatFilm& f : batch_films) f.KeepOnly(window->x0, window->y0, window->width, window->height);
    }
    // Every integrator's camera samples get their instants, those whose tiles read a scene
    // pass's product too: its photons and light vertices were traced at instants of their
    // own (LightPathInstant), its radiosity solution at mid-shutter (docs/motion.md).
    const bool sample_time = kFullFeatures && (scene.has_motion() || camera.Moves());
    std::atomic<uint64_t> nonfinite{0}, rejected_splats{0}, closest_rays{0}, shadow_rays{0};
    const bool want_aovs = kFullFeatures && aovs.any();
    std::mutex first_mutex;
    RenderStats stats;
    const uint32_t n_pixels = tile.width * tile.height;
    // Batches are of a still shutter: a moving scene or camera keeps one instant per sample.
    const bool in_batches = integrator->samples_in_batches() && !sample_time;
    constexpr uint32_t kBatchSamples = 256;
    const uint32_t chunk = in_batches ? kBatchSamples : 1;

    const TextureFootprintCamera footprint_camera = FootprintCameraOf(camera);
    const bool filter_textures = kFullFeatures && TextureFilteringOn();

    auto render_range = [&](const tbb::blocked_range<uint32_t>& range) {
        ScopedFlushDenormals ftz;
        const TextureFootprintScope footprint(filter_textures ? &footprint_camera : nullptr);
        IntegratorCounters counters;
        const RayCounters rays_before = tls_ray_counters;
        RayCounters aov_rays;  // traced for the AOVs: not the integrators' rays
        // An integrator that estimates batches (the lane kernel) gets a pixel's samples up to
        // kBatchSamples at a time; the others one at a time, as a splatting one needs (its
        // variance batch is chosen per sample).
        std::vector<BatchSample> batch_samples;
        std::vector<PathSample> results(chunk);
        batch_samples.reserve(chunk);
        for (uint32_t i = range.begin(); i != range.end(); ++i) {
            const uint32_t x = tile.x0 + i % tile.width, y = tile.y0 + i / tile.width;
            const uint64_t pixel_index = uint64_t(y) * camera.width + x;
            // Outside the camera window a pixel's own estimate is not wanted: it stays 0, and
            // only a splatting integrator's light paths are traced (their splats may land inside).
            const bool inside = !window || window->Contains(x, y);
            const uint32_t spp_here = inside || info.splats ? options.spp : 0;
            // Double sums in sample order: the same pixel always sums the same values in
            // the same order, whatever thread runs it.
            double sum_r = 0, sum_g = 0, sum_b = 0, sum_a = 0;
            double sq_r = 0, sq_g = 0, sq_b = 0;
            double aov_albedo[3] = {0, 0, 0}, aov_normal[3] = {0, 0, 0}, aov_depth = 0;
            uint32_t aov_hits = 0;
            // The batch this sample belongs to, where it ends, and its own sums (in sample
            // order, as a render of that batch's range alone would add them).
            uint32_t batch = 0;
            uint32_t batch_end = options.sample_start +
                                 (batches.count ? VarianceBatchRange(options.spp, batches.count, 0).second : options.spp);
            double batch_r = 0, batch_g = 0, batch_b = 0;
            const uint32_t end = options.sample_start + spp_here;
            for (uint32_t s0 = options.sample_start; s0 < end; s0 += chunk) {
                const uint32_t count = std::min(chunk, end - s0);
                batch_samples.clear();
                for (uint32_t s = s0; s < s0 + count; ++s) {
                    PixelSampler sampler(options.seed, pixel_index, s, /*stream=*/0, options.sampler);
                    Vec2 jitter = sampler.Get2D();
                    // The lens dimensions are drawn only for a lens, so pinhole images keep
                    // their sample streams.
                    const Vec2 u_lens = kFullFeatures && camera.HasLens() ? sampler.Get2D() : Vec2{0.5f, 0.5f};
                    // The sample's instant in the shutter (a box shutter): its own dimension,
                    // drawn only when something moves, so static images keep their streams.
                    const float time = sample_time ? sampler.Get1D() : 0.5f;
                    const ShutterTimeScope instant(time);
                    // A moving camera, where it is at that instant (for the ray, the AOVs and
                    // every connection the integrator makes to the camera).
                    std::optional<Camera> moved;
                    if (kFullFeatures && camera.Moves()) moved = camera.At(time);
                    const Camera& cam = moved ? *moved : camera;
                    Ray ray = cam.GenerateRay(float(x) + jitter.x, float(y) + jitter.y, u_lens);
                    float t_min, t_max;
                    cam.ClipRange(ray.d, &t_min, &t_max);
                    if (want_aovs && inside) {
                        // Its own sample stream, so the image is the same with or without AOVs.
                        const RayCounters before = tls_ray_counters;
                        PixelSampler aov_sampler(options.seed, pixel_index, s, /*stream=*/2, options.sampler);
                        const AOVSample a = SampleAOVs(scene, cam, ray, t_min, t_max, options.max_depth, aov_sampler);
                        aov_rays.closest += tls_ray_counters.closest - before.closest;
                        aov_rays.shadow += tls_ray_counters.shadow - before.shadow;
                        for (int c = 0; c < 3; ++c) {
                            aov_albedo[c] += a.albedo[c];
                            aov_normal[c] += a.normal[c];
                        }
                        if (a.hit) {
                            aov_depth += a.depth;
                            ++aov_hits;
                        }
                    }
                    const CameraSample cs{ray, t_min, t_max, options.seed, pixel_index, s, options.sampler, inside};
                    if (in_batches) {
                        batch_samples.push_back({ray, t_min, t_max, sampler});
                        continue;
                    }
                    SplatFilm& sample_film = batches.count ? batch_films[batch] : film;
                    results[s - s0] = integrator->Sample(scene, cam, cs, sampler, sample_film, &counters);
                }
                if (in_batches) integrator->SampleBatch(scene, batch_samples.data(), results.data(), count);
                // Summed in sample order, however the samples were estimated.
                for (uint32_t s = s0; s < s0 + count; ++s) {
                    const PathSample& ps = results[s - s0];
                    if (!inside) {
                        // Not wanted: an integrator that ignores camera_work computed it all the same.
                    } else if (!IsFinite(ps.radiance)) {
                        if (nonfinite.fetch_add(1) == 0) {
                            std::lock_guard<std::mutex> lock(first_mutex);
                            stats.first_nonfinite_pixel_x = x;
                            stats.first_nonfinite_pixel_y = y;
                            stats.first_nonfinite_sample = s;
                        }
                    } else {
                        sum_r += ps.radiance.x;
                        sum_g += ps.radiance.y;
                        sum_b += ps.radiance.z;
                        sum_a += ps.alpha;
                        sq_r += double(ps.radiance.x) * ps.radiance.x;
                        sq_g += double(ps.radiance.y) * ps.radiance.y;
                        sq_b += double(ps.radiance.z) * ps.radiance.z;
                        batch_r += ps.radiance.x;
                        batch_g += ps.radiance.y;
                        batch_b += ps.radiance.z;
                    }
                    if (batches.count && s + 1 == batch_end) {
                        const double n = double(VarianceBatchRange(options.spp, batches.count, batch).second);
                        float* out = batches.rgb + (size_t(batch) * n_pixels + i) * 3;
                        out[0] = float(batch_r * (1.0 / n));
                        out[1] = float(batch_g * (1.0 / n));
                        out[2] = float(batch_b * (1.0 / n));
                        batch_r = batch_g = batch_b = 0;
                        if (++batch < batches.count)
                            batch_end += VarianceBatchRange(options.spp, batches.count, batch).second;
                    }
                }
            }
            const double inv = 1.0 / double(options.spp);
            float* out = rgba + 4 * size_t(i);
            out[0] = float(sum_r * inv);
            out[1] = float(sum_g * inv);
            out[2] = float(sum_b * inv);
            out[3] = float(sum_a * inv);
            if (variance) {
                // Unbiased sample variance from the sums; 0 for a single sample.
                const double n = double(options.spp);
                auto var = [n](double sum, double sq) {
                    return n > 1.0 ? std::max(0.0, (sq - sum * sum / n) / (n - 1.0)) : 0.0;
                };
                float* v = variance + 3 * size_t(i);
                v[0] = float(var(sum_r, sq_r));
                v[1] = float(var(sum_g, sq_g));
                v[2] = float(var(sum_b, sq_b));
            }
            if (want_aovs && !inside) {
                for (float* layer : {aovs.albedo, aovs.normal})
                    if (layer) std::fill_n(layer + 3 * size_t(i), 3, 0.f);
                if (aovs.depth) aovs.depth[i] = 0.f;
                if (aovs.samples) aovs.samples[i] = 0.f;
            } else if (want_aovs) {
                for (int c = 0; c < 3; ++c) {
                    if (aovs.albedo) aovs.albedo[3 * size_t(i) + c] = float(aov_albedo[c] * inv);
                    if (aovs.normal) aovs.normal[3 * size_t(i) + c] = float(aov_normal[c] * inv);
                }
                if (aovs.depth)
                    aovs.depth[i] = aov_hits ? float(aov_depth / aov_hits) : std::numeric_limits<float>::infinity();
                if (aovs.samples) aovs.samples[i] = float(options.spp);
            }
        }
        if (counters.rejected_splats) rejected_splats.fetch_add(counters.rejected_splats);
        closest_rays.fetch_add(tls_ray_counters.closest - rays_before.closest - aov_rays.closest,
                               std::memory_order_relaxed);
        shadow_rays.fetch_add(tls_ray_counters.shadow - rays_before.shadow - aov_rays.shadow,
                              std::memory_order_relaxed);
    };

    const int threads = options.threads > 0 ? options.threads : tbb::this_task_arena::max_concurrency();
    tbb::task_arena arena(threads);
    arena.execute([&] { tbb::parallel_for(tbb::blocked_range<uint32_t>(0, n_pixels, 8), render_range); });

    uint64_t sampled_pixels = n_pixels;  // a splatting integrator samples every pixel for its light paths
    if (window && !info.splats) {
        const auto overlap = [](uint32_t a0, uint32_t a1, uint32_t b0, uint32_t b1) {
            return uint64_t(std::max<int64_t>(0, int64_t(std::min(a1, b1)) - int64_t(std::max(a0, b0))));
        };
        sampled_pixels = overlap(tile.x0, tile.x0 + tile.width, window->x0, window->x0 + window->width) *
                         overlap(tile.y0, tile.y0 + tile.height, window->y0, window->y0 + window->height);
    }
    stats.samples = sampled_pixels * options.spp;
    stats.nonfinite_samples = nonfinite.load();
    stats.light_paths = info.splats ? stats.samples : 0;
    stats.rejected_splats = rejected_splats.load();
    stats.closest_rays = closest_rays.load();
    stats.shadow_rays = shadow_rays.load();
    return stats;
}

std::string RunScenePass(const Scene& scene, const RenderOptions& options, uint32_t iteration) {
    const std::unique_ptr<Integrator> integrator =
        Integrator::Create(options.integrator, {options.max_depth, options.integrator_params}, scene);
    if (!integrator->info().scene_passes)
        throw std::invalid_argument("integrator '" + options.integrator + "' has no scene-wide passes");
    return integrator->RunScenePass(scene, options.seed, iteration, options.threads);
}

}  // namespace tessera
