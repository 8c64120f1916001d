#include "stochastic_solver.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <optional>

#include "sampler.h"
#include "sampling.h"

namespace tessera {

namespace {

// Sampler streams of the shooting rays: element-side indices offset past every image's
// pixels and past the light gathering's (2^41, progressive_solver.cpp).
constexpr uint64_t kShootStreamBase = uint64_t(3) << 41;
constexpr uint32_t kShootStream = 16;  // + the iteration
// Specular bounces a shooting ray may take before it is dropped.
constexpr int kMaxSpecularBounces = 16;
// Rays per parallel chunk and per block whose deposits are merged (in ray order) before
// the next block is traced: bounded memory, and sums that no thread count changes.
constexpr uint64_t kChunkRays = 4096;
constexpr uint64_t kBlockChunks = 64;

double Power(Color c, float area) { return double(Luminance(c)) * area; }

struct Shooter {
    uint32_t side;       // element side 2 e + s
    uint64_t first;      // its rays are [first, next shooter's first)
    Color ray_power;     // W carried by each of its rays
};

struct Deposit {
    uint32_t side;
    Color power;  // W
};

// Shoots `radiosity` (W m^-2 per element side) along about `rays` rays and returns the
// radiosity each element side receives (reflectance applied). Adds the power it shot and the
// part that landed on a reflecting element to sol's closure counts, and its rays to sol->rays.
std::vector<Color> Shoot(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings,
                         tbb::task_arena& arena, const std::vector<Color>& radiosity, double rays, uint32_t iteration,
                         RadiositySolution* sol) {
    uint64_t* cast = &sol->rays;
    const std::vector<RadiosityElement>& el = mesh.elements();
    std::vector<Color> received(radiosity.size(), Color(0.f));
    double total = 0.0;
    for (size_t k = 0; k < radiosity.size(); ++k)
        if (el[k / 2].area > 0.f) total += std::max(0.0, Power(radiosity[k], el[k / 2].area));
    if (!(total > 0.0) || !(rays >= 1.0)) return received;

    // Systematic sampling of the sides by power: ray r belongs to the side whose stretch of
    // the cumulative power holds (r + u0) delta, so every ray carries luminance power delta
    // and side k casts its power / delta rays in expectation (u0 random: unbiased).
    const double delta = total / rays;
    const double u0 = double(Mix64(Mix64(settings.seed) ^ (0x9E3779B97F4A7C15ull * (iteration + 1))) >> 11) * 0x1p-53;
    std::vector<Shooter> shooters;
    double cumulative = 0.0;
    uint64_t next = 0;
    for (size_t k = 0; k < radiosity.size(); ++k) {
        const float area = el[k / 2].area;
        const double p = area > 0.f ? Power(radiosity[k], area) : 0.0;
        if (!(p > 0.0)) continue;
        cumulative += p;
        const uint64_t end = uint64_t(std::max(0.0, std::ceil(cumulative / delta - u0)));
        if (end > next)
            shooters.push_back({uint32_t(k), next, radiosity[k] * float(area * delta / p)});
        next = std::max(next, end);
    }
    const uint64_t count = next;
    *cast += count;
    uint64_t landed_rays = 0, *landed = &landed_rays;

    const float eps = RadiosityLengthScale(scene);
    const bool through_delta = scene.has_delta_surfaces();
    const uint64_t chunks = (count + kChunkRays - 1) / kChunkRays;
    std::vector<std::vector<Deposit>> deposits(kBlockChunks);
    for (uint64_t block = 0; block < chunks; block += kBlockChunks) {
        const uint64_t block_end = std::min(chunks, block + kBlockChunks);
        arena.execute([&] {
            tbb::parallel_for(tbb::blocked_range<uint64_t>(block, block_end, 1), [&](const tbb::blocked_range<uint64_t>& cr) {
                const ShutterTimeScope instant(settings.shutter_time);
                for (uint64_t c = cr.begin(); c != cr.end(); ++c) {
                    std::vector<Deposit>& out = deposits[c - block];
                    out.clear();
                    const uint64_t r0 = c * kChunkRays, r1 = std::min(count, r0 + kChunkRays);
                    size_t s = size_t(std::upper_bound(shooters.begin(), shooters.end(), r0,
                                                       [](uint64_t r, const Shooter& x) { return r < x.first; }) -
                                      shooters.begin()) - 1;
                    for (uint64_t r = r0; r < r1; ++r) {
                        while (s + 1 < shooters.size() && shooters[s + 1].first <= r) ++s;
                        const Shooter& sh = shooters[s];
                        const RadiosityElement& e = el[sh.side / 2];
                        const Vec3 ns = (sh.side % 2) ? -e.n : e.n;
                        PixelSampler sampler(settings.seed, kShootStreamBase + sh.side, uint32_t(r - sh.first),
                                             kShootStream + iteration, SamplerKind::kOwenSobol);
                        const Vec3 b = SampleUniformTriangle(sampler.Get2D());
                        const Vec3 p = e.p[0] * b.x + e.p[1] * b.y + e.p[2] * b.z;
                        const Vec3 d = Frame::FromZ(ns).FromLocal(SampleCosineHemisphere(sampler.Get2D()));
                        Ray ray{p + ns * eps, d};
                        Color power = sh.ray_power;
                        SurfaceHit hit;
                        bool landed = false;
                        // Across surfaces with only delta lobes (smooth mirrors, clear glass) the
                        // ray goes on as their BSDF sends it: Wallace's extended form factors,
                        // sampled, so the light a mirror or a glass sphere throws onto a wall
                        // is in the solution.
                        for (int bounce = 0; bounce <= kMaxSpecularBounces; ++bounce) {
                            if (!scene.Intersect(ray, &hit)) break;
                            if (!through_delta) {
                                landed = true;
                                break;
                            }
                            const BSDF bsdf = scene.BSDFAt(hit, TransportMode::Importance);
                            if (bsdf.IsNonSpecular() || !bsdf.HasDelta()) {
                                landed = true;
                                break;
                            }
                            const Frame frame = Frame::FromZ(hit.ns);
                            const Vec3 wo = -ray.d, wo_local = frame.ToLocal(wo);
                            const float uc = sampler.Get1D();
                            const std::optional<BSDFSample> bs = bsdf.Sample_f(wo_local, uc, sampler.Get2D());
                            if (!bs || !(bs->pdf > 0.f) || IsBlack(bs->f)) break;
                            const Vec3 wi = Normalize(frame.FromLocal(bs->wi));
                            if (!SidesAgree(wo, wi, hit.ng, wo_local, bs->wi)) break;
                            power = power * bs->f * (std::abs(bs->wi.z) / bs->pdf);
                            ray = {OffsetRayOrigin(hit.p, hit.p_error, hit.ng, wi), wi};
                        }
                        if (!landed) continue;
                        float w[3];
                        const int32_t j = mesh.Locate(hit, w);
                        if (j < 0 || IsBlack(el[j].rho) || !(el[j].area > 0.f)) continue;
                        const uint32_t side = Dot(ray.d, el[j].n) < 0.f ? 0u : 1u;
                        out.push_back({2 * uint32_t(j) + side, el[j].rho * power});
                    }
                }
            });
        });
        for (uint64_t c = block; c < block_end; ++c) {
            for (const Deposit& d : deposits[c - block]) received[d.side] += d.power;
            *landed += deposits[c - block].size();
        }
    }
    for (size_t k = 0; k < received.size(); ++k)
        if (el[k / 2].area > 0.f) received[k] = received[k] / el[k / 2].area;
    if (count > 0) {
        (iteration == 0 ? sol->emission_shot_power : sol->shot_power) += total;
        (iteration == 0 ? sol->emission_landed_power : sol->landed_power) += total * double(landed_rays) / double(count);
    }
    return received;
}

}  // namespace

RadiositySolution SolveStochastic(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings) {
    const std::vector<RadiosityElement>& el = mesh.elements();
    const size_t n = el.size();
    RadiositySolution sol = ZeroSolution(n);
    if (n == 0) return sol;
    tbb::task_arena arena(settings.threads > 0 ? settings.threads : tbb::this_task_arena::max_concurrency());
    GatherUnmeshedDirect(scene, mesh, settings, arena, &sol);

    auto unshot_power = [&] {
        double u = 0.0;
        for (size_t k = 0; k < 2 * n; ++k) u += Power(sol.unshot[k], el[k / 2].area);
        return u;
    };
    std::vector<Color> emission(2 * n, Color(0.f));
    for (size_t i = 0; i < n; ++i)
        for (int s = 0; s < 2; ++s) {
            emission[2 * i + s] = el[i].emission[s];
            sol.radiosity[2 * i + s] += el[i].emission[s];
            if (el[i].area > 0.f) sol.entered_power += Power(el[i].emission[s], el[i].area);
        }
    sol.entered_power += unshot_power();  // the gathered direct light
    if (!(sol.entered_power > 0.0)) {
        sol.converged = true;
        return sol;
    }
    const double first_rays = settings.first_rays > 0.0 ? settings.first_rays : double(settings.rays_per_element) * double(n);

    // Iteration 0: the emission, once; what it deposits is direct light.
    const std::vector<Color> direct = Shoot(scene, mesh, settings, arena, emission, first_rays, 0, &sol);
    for (size_t k = 0; k < 2 * n; ++k) {
        sol.radiosity[k] += direct[k];
        sol.direct[k] += direct[k];
        sol.unshot[k] += direct[k];
    }
    const uint32_t max_iterations = settings.max_shots ? settings.max_shots : 1000u;
    const double target = settings.tolerance * sol.entered_power;
    double u = unshot_power();
    sol.residual.push_back(u);
    while (u > target && sol.shots < max_iterations) {
        ++sol.shots;
        const double rays = std::max(double(n), first_rays * u / sol.entered_power);
        std::vector<Color> shot(2 * n, Color(0.f));
        shot.swap(sol.unshot);
        const std::vector<Color> received = Shoot(scene, mesh, settings, arena, shot, rays, sol.shots, &sol);
        for (size_t k = 0; k < 2 * n; ++k) {
            sol.radiosity[k] += received[k];
            sol.unshot[k] = received[k];
        }
        u = unshot_power();
        sol.residual.push_back(u);
    }
    sol.converged = u <= target;
    SetAmbient(mesh, &sol);
    return sol;
}

}  // namespace tessera
