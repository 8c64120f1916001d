#include "point_direct.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>

#include "form_factor.h"

namespace tessera {

namespace {

// Sampler streams of the point evaluations, apart from the elements' (below 2^33): the
// vertices' from 2^34, the centroids' from 2^35.
constexpr uint64_t kVertexStreams = uint64_t(1) << 34;
constexpr uint64_t kCentroidStreams = uint64_t(1) << 35;

}  // namespace

PointDirect::PointDirect(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings)
    : scene_(scene), mesh_(mesh), settings_(settings), unmeshed_(UnmeshedLights(scene, mesh)) {
    eps_ = RadiosityLengthScale(scene);
    const auto& el = mesh.elements();
    for (uint32_t e = 0; e < el.size(); ++e)
        if ((!IsBlack(el[e].emission[0]) || !IsBlack(el[e].emission[1])) && el[e].area > 0.f) emissive_.push_back(e);
}

Color PointDirect::Irradiance(Vec3 x, Vec3 n, uint64_t stream) const {
    Color e(0.f);
    const auto& el = mesh_.elements();
    for (uint32_t j : emissive_) {
        const RadiosityElement& src = el[j];
        const float h = Dot(x - src.center, src.n);
        if (h == 0.f) continue;
        const int side = h > 0.f ? 0 : 1;
        const Color emission = src.emission[side];
        if (IsBlack(emission)) continue;
        const Vec3 ns = side ? -src.n : src.n;
        // The 4 half-edge sub-triangles: each its exact factor, seen when the ray to its
        // centroid is clear (exact wherever the emitter is wholly seen or wholly hidden).
        const Vec3 m01 = (src.p[0] + src.p[1]) * 0.5f, m12 = (src.p[1] + src.p[2]) * 0.5f,
                   m20 = (src.p[2] + src.p[0]) * 0.5f;
        const Vec3 sub[4][3] = {{src.p[0], m01, m20}, {m01, src.p[1], m12}, {m20, m12, src.p[2]}, {m12, m20, m01}};
        float F = 0.f;
        for (const auto& t : sub) {
            const float f = PointToTriangleFormFactor(x, n, t);
            if (!(f > 0.f)) continue;
            const Vec3 c = (t[0] + t[1] + t[2]) / 3.f;
            if (scene_.Unoccluded(x, eps_, n, c, eps_, ns)) F += f;
        }
        e += emission * F;
    }
    if (!unmeshed_.empty())
        e += GatherIrradiance(scene_, x, n, unmeshed_, kPointSamplesPerLightSample * settings_.light_samples,
                              settings_.seed, stream, eps_);
    return e;
}

std::vector<Color> VertexPointDirect(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings,
                                     tbb::task_arena& arena) {
    const PointDirect direct(scene, mesh, settings);
    const size_t nv = mesh.num_vertices();
    if (double(2 * nv) * double(direct.cost()) > kPointDirectBudget) return {};
    const auto& el = mesh.elements();
    std::vector<Vec3> where(nv), normal(nv), inward(nv, Vec3(0.f));
    std::vector<Color> rho(2 * nv, Color(0.f));
    std::vector<float> area(nv, 0.f);
    for (const RadiosityElement& e : el)
        for (int k = 0; k < 3; ++k) {
            where[e.vertex[k]] = e.p[k];
            normal[e.vertex[k]] = e.n;
            rho[e.vertex[k]] += e.rho * e.area;
            area[e.vertex[k]] += e.area;
            inward[e.vertex[k]] += (e.center - e.p[k]) * e.area;
        }
    // A vertex on a surface's border (a floor's edge along a wall) is evaluated a few ray
    // offsets inside its elements: at the border itself its shadow rays would start on the
    // wall and find it in the way (the seams along a room's edges went dark). An inner
    // vertex's elements surround it, so it hardly moves.
    const float nudge = 4.f * RadiosityLengthScale(scene);
    for (size_t v = 0; v < nv; ++v) {
        if (!(area[v] > 0.f)) continue;
        const Vec3 d = inward[v] / area[v];
        const float len = Length(d);
        if (len > 0.f) where[v] += d * (std::min(nudge, 0.5f * len) / len);
    }
    std::vector<Color> out(2 * nv, Color(0.f));
    arena.execute([&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, 2 * nv, 64), [&](const tbb::blocked_range<size_t>& r) {
            const ShutterTimeScope instant(settings.shutter_time);
            for (size_t k = r.begin(); k != r.end(); ++k) {
                const size_t v = k / 2;
                if (!(area[v] > 0.f)) continue;
                const Color rv = rho[v] / area[v];
                if (IsBlack(rv)) continue;
                const Vec3 n = (k % 2) ? -normal[v] : normal[v];
                out[k] = rv * direct.Irradiance(where[v], n, kVertexStreams + k);
            }
        });
    });
    mesh.SettleHanging(&out);
    return out;
}

std::vector<Color> CentroidPointDirect(const Scene& scene, const RadiosityMesh& mesh,
                                       const RadiositySettings& settings, tbb::task_arena& arena) {
    const PointDirect direct(scene, mesh, settings);
    const auto& el = mesh.elements();
    std::vector<Color> out(2 * el.size(), Color(0.f));
    arena.execute([&] {
        tbb::parallel_for(tbb::blocked_range<size_t>(0, out.size(), 64), [&](const tbb::blocked_range<size_t>& r) {
            const ShutterTimeScope instant(settings.shutter_time);
            for (size_t k = r.begin(); k != r.end(); ++k) {
                const RadiosityElement& e = el[k / 2];
                if (IsBlack(e.rho)) continue;
                out[k] = e.rho * direct.Irradiance(e.center, (k % 2) ? -e.n : e.n, kCentroidStreams + k);
            }
        });
    });
    return out;
}

}  // namespace tessera
