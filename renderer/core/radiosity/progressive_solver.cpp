#include "progressive_solver.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <unordered_set>

#include "form_factor.h"
#include "sampler.h"

namespace tessera {

namespace {

// Sampler streams of the light gathering: a pixel-index range no image reaches (2^41),
// apart from photon_direct's (2^40).
constexpr uint64_t kGatherStreamBase = uint64_t(1) << 41;
constexpr uint32_t kGatherStream = 4;
// Form factors kept for reuse when an element shoots again, at most (64 MB of floats).
constexpr size_t kFactorCacheBudget = size_t(16) << 20;

double Power(Color c, float area) { return double(Luminance(c)) * area; }

}  // namespace

std::vector<uint32_t> UnmeshedLights(const Scene& scene, const RadiosityMesh& mesh) {
    std::unordered_set<int32_t> meshed;
    for (const RadiosityElement& e : mesh.elements())
        if (e.emitter != Scene::kNoEmitter) meshed.insert(e.emitter);
    std::vector<uint32_t> other;
    for (uint32_t e = 0; e < scene.num_emitters(); ++e)
        if (!meshed.count(int32_t(e))) other.push_back(e);
    return other;
}

Color GatherIrradiance(const Scene& scene, Vec3 x, Vec3 n, const std::vector<uint32_t>& lights, uint32_t samples,
                       uint32_t seed, uint64_t stream, float eps) {
    Color irradiance(0.f);
    for (uint32_t s = 0; s < samples; ++s) {
        PixelSampler sampler(seed, kGatherStreamBase + stream, s, kGatherStream);
        for (uint32_t light : lights) {
            LightSample ls;
            const Vec2 u = sampler.Get2D();
            if (!scene.SampleEmitter(light, x, u, &ls) || !(ls.pdf > 0.f)) continue;
            const float cos = Dot(ls.wi, n);
            if (!(cos > 0.f) || IsBlack(ls.radiance)) continue;
            if (!scene.Unoccluded(x, eps, n, ls)) continue;
            irradiance += ls.radiance * (cos / ls.pdf);
        }
    }
    return irradiance / float(std::max(1u, samples));
}

RadiositySolution ZeroSolution(size_t elements) {
    RadiositySolution sol;
    sol.radiosity.assign(2 * elements, Color(0.f));
    sol.direct.assign(2 * elements, Color(0.f));
    sol.unshot.assign(2 * elements, Color(0.f));
    sol.converged = elements == 0;
    return sol;
}

void GatherUnmeshedDirect(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings,
                          tbb::task_arena& arena, RadiositySolution* sol) {
    const std::vector<uint32_t> other_lights = UnmeshedLights(scene, mesh);
    if (other_lights.empty()) return;
    const std::vector<RadiosityElement>& el = mesh.elements();
    const float eps = RadiosityLengthScale(scene);
    arena.execute([&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, 2 * el.size(), 64), [&](const tbb::blocked_range<size_t>& r) {
            const ShutterTimeScope instant(settings.shutter_time);
            for (size_t k = r.begin(); k != r.end(); ++k) {
                const RadiosityElement& e = el[k / 2];
                if (IsBlack(e.rho)) continue;
                const Vec3 nr = (k % 2) ? -e.n : e.n;
                const Color b = e.rho * GatherIrradiance(scene, e.center, nr, other_lights, settings.light_samples,
                                                         settings.seed, k, eps);
                sol->direct[k] = b;
                sol->radiosity[k] = b;
                sol->unshot[k] = b;
            }
        });
    });
}

void SetAmbient(const RadiosityMesh& mesh, RadiositySolution* sol) {
    // Ambient (Cohen et al. 1988): the unshot power spread uniformly and interreflected
    // with the mean reflectance, over the element sides that take part (received light).
    const std::vector<RadiosityElement>& el = mesh.elements();
    Color unshot_area(0.f), rho_area(0.f);
    float area = 0.f;
    for (size_t k = 0; k < 2 * el.size(); ++k) {
        if (!(Luminance(sol->radiosity[k]) > 0.f)) continue;
        unshot_area += sol->unshot[k] * el[k / 2].area;
        rho_area += el[k / 2].rho * el[k / 2].area;
        area += el[k / 2].area;
    }
    sol->ambient = Color(0.f);
    if (!(area > 0.f)) return;
    // Cohen's ambient assumes a closed scene: all the unshot power lands and interreflects
    // with the mean reflectance. Where part of every shot escapes (an open scene: a plane
    // under a light) that overstates it, and a constant added everywhere is largest,
    // relatively, where the light is dim: a lit plane's far corners were 4 % too bright.
    // So only the fraction of shot power that did land is spread, and it interreflects
    // with rho times that fraction.
    const double closure_d = sol->shot_power > 0.0            ? sol->landed_power / sol->shot_power
                             : sol->emission_shot_power > 0.0 ? sol->emission_landed_power / sol->emission_shot_power
                                                              : 1.0;
    const float closure = float(std::clamp(closure_d, 0.0, 1.0));
    const Color rho_avg = rho_area / area * closure;
    const Color u = unshot_area / area * closure;
    sol->ambient = Color(rho_avg.x < 1.f ? u.x / (1.f - rho_avg.x) : 0.f, rho_avg.y < 1.f ? u.y / (1.f - rho_avg.y) : 0.f,
                         rho_avg.z < 1.f ? u.z / (1.f - rho_avg.z) : 0.f);
}

RadiositySolution SolveProgressive(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings) {
    const std::vector<RadiosityElement>& el = mesh.elements();
    const size_t n = el.size();
    RadiositySolution sol = ZeroSolution(n);
    if (n == 0) return sol;
    const float eps = RadiosityLengthScale(scene);
    tbb::task_arena arena(settings.threads > 0 ? settings.threads : tbb::this_task_arena::max_concurrency());

    // Step 1a: lights that are not meshed, gathered per element side.
    GatherUnmeshedDirect(scene, mesh, settings, arena, &sol);
    for (size_t i = 0; i < n; ++i)
        for (int s = 0; s < 2; ++s) {
            sol.radiosity[2 * i + s] += el[i].emission[s];
            sol.unshot[2 * i + s] += el[i].emission[s];
        }

    // The receivers of element side (i, s): F_ji for every j, negative where j receives on
    // its back. Kept for reuse while the cache budget lasts.
    std::vector<std::vector<float>> cache(2 * n);
    size_t cached = 0;
    std::vector<float> scratch(n);
    auto column = [&](size_t i, int s) -> const std::vector<float>& {
        std::vector<float>& c = cache[2 * i + s];
        if (!c.empty()) return c;
        std::vector<float>& out = cached + n <= kFactorCacheBudget ? c : scratch;
        out.assign(n, 0.f);
        const RadiosityElement& src = el[i];
        const Vec3 ns = s ? -src.n : src.n;
        arena.execute([&] {
            tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 64), [&](const tbb::blocked_range<size_t>& r) {
                const ShutterTimeScope instant(settings.shutter_time);
                for (size_t j = r.begin(); j != r.end(); ++j) {
                    const RadiosityElement& rec = el[j];
                    if (j == i || IsBlack(rec.rho)) continue;
                    const Vec3 d = src.center - rec.center;
                    if (!(Dot(d, ns) < 0.f)) continue;  // behind the shooting side
                    const float h = Dot(d, rec.n);
                    if (h == 0.f) continue;
                    const Vec3 nr = h > 0.f ? rec.n : -rec.n;
                    float Fk[4];
                    float f = ReceiverMeanFormFactor(rec.p, nr, src.p, Fk);
                    if (f > 0.f) f = VisibleReceiverMeanFormFactor(scene, rec.p, nr, src.p, ns, eps, Fk, nullptr);
                    out[j] = h > 0.f ? f : -f;
                }
            });
        });
        if (&out == &c) cached += n;
        return out;
    };
    auto shoot = [&](size_t i, int s, Color amount, bool is_direct) {
        const std::vector<float>& f = column(i, s);
        double landed = 0.0;
        for (size_t j = 0; j < n; ++j) {
            if (f[j] == 0.f) continue;
            landed += double(std::abs(f[j])) * el[j].area;
            const size_t k = 2 * j + (f[j] > 0.f ? 0 : 1);
            const Color db = el[j].rho * amount * std::abs(f[j]);
            sol.radiosity[k] += db;
            sol.unshot[k] += db;
            if (is_direct) sol.direct[k] += db;
        }
        // Reciprocity: sum_j F_ji A_j / A_i is the fraction of i's power that lands.
        if (el[i].area > 0.f) {
            const double power = Power(amount, el[i].area);
            (is_direct ? sol.emission_shot_power : sol.shot_power) += power;
            (is_direct ? sol.emission_landed_power : sol.landed_power) += power * std::min(1.0, landed / el[i].area);
        }
    };

    // Step 1b: every emissive element side shoots its emission once.
    for (size_t i = 0; i < n; ++i)
        for (int s = 0; s < 2; ++s) {
            const Color e = el[i].emission[s];
            if (IsBlack(e) || !(el[i].area > 0.f)) continue;
            sol.entered_power += Power(e, el[i].area);
            sol.unshot[2 * i + s] = sol.unshot[2 * i + s] - e;
            shoot(i, s, e, true);
        }
    for (size_t k = 0; k < 2 * n; ++k) sol.entered_power += Power(sol.direct[k], el[k / 2].area);

    // Step 2: Southwell iteration on what is unshot.
    auto residual = [&] {
        double r = 0.0;
        for (size_t k = 0; k < 2 * n; ++k) r += Power(sol.unshot[k], el[k / 2].area);
        return r;
    };
    const uint32_t max_shots = settings.max_shots ? settings.max_shots : uint32_t(std::min<size_t>(100 * n, 1u << 30));
    double r = residual();
    sol.residual.push_back(r);
    const double target = settings.tolerance * sol.entered_power;
    while (r > target && sol.shots < max_shots) {
        size_t best = 0;
        double best_power = -1.0;
        for (size_t k = 0; k < 2 * n; ++k) {
            const double p = Power(sol.unshot[k], el[k / 2].area);
            if (p > best_power) best_power = p, best = k;
        }
        if (!(best_power > 0.0)) break;
        const Color amount = sol.unshot[best];
        sol.unshot[best] = Color(0.f);
        shoot(best / 2, int(best % 2), amount, false);
        ++sol.shots;
        // The residual is re-summed, not updated, so rounding cannot drift it.
        r = residual();
        sol.residual.push_back(r);
    }
    sol.converged = r <= target;
    sol.cached_factors = cached;

    SetAmbient(mesh, &sol);
    return sol;
}

std::vector<Color> ReflectedRadiosity(const RadiosityMesh& mesh, const RadiositySolution& solution) {
    const std::vector<RadiosityElement>& el = mesh.elements();
    std::vector<Color> out(2 * el.size());
    for (size_t k = 0; k < out.size(); ++k) {
        const RadiosityElement& e = el[k / 2];
        const Color b = solution.radiosity[k] - e.emission[k % 2] + e.rho * solution.ambient;
        out[k] = Color(std::max(0.f, b.x), std::max(0.f, b.y), std::max(0.f, b.z));
    }
    return out;
}

}  // namespace tessera
