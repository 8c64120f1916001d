#include "radiosity_product.h"

#include "hierarchical_solver.h"
#include "point_direct.h"
#include "stochastic_solver.h"
#include "shutter_slices.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <mutex>
#include <stdexcept>

namespace tessera {

namespace {

// The product: an outer header naming the time slices, then one block per slice, each a
// Header, the mesh's refinement (each element's quadtree depth, one byte, when refined) and
// its four arrays.
constexpr char kMagic[4] = {'T', 'R', 'A', '3'};
struct OuterHeader {
    char magic[4];
    uint32_t time_slices;
};
constexpr char kSliceMagic[4] = {'T', 'R', 'A', 'S'};
struct Header {
    char magic[4];
    uint32_t elements;
    uint32_t vertices;
    uint32_t shots;
    float relative_residual;  // unshot / entered power at the end
    uint32_t converged;
    uint32_t cells;           // uniform cells of the mesh
    uint32_t depth_bytes;     // 0 (not refined) or elements: each leaf's depth (radiosity_mesh.h)
};
// Default element size as a fraction of the scene's bounding diameter (unit-free).
constexpr float kDefaultElementOfDiameter = 1.f / 10.f;
// Rounds of adaptive meshing when refine_levels is not set (solvers 0 and 2).
constexpr uint32_t kDefaultRefineLevels = 3;
constexpr size_t kDefaultRefineBudget = 8192;

void Append(std::string* out, const std::vector<Color>& v) {
    const size_t at = out->size();
    out->resize(at + v.size() * sizeof(Color));
    if (!v.empty()) std::memcpy(out->data() + at, v.data(), v.size() * sizeof(Color));
}

}  // namespace

const std::vector<IntegratorParam>& RadiosityParams() {
    static const std::vector<IntegratorParam> params = {
    {"element_size", "longest edge of a radiosity element, scene units (default: a tenth of the scene's "
                     "bounding diameter)"},
    {"tolerance", "progressive: stop shooting when the unshot power is below this fraction of the emitted "
                  "(default 0.001); hierarchical: refine a link while its BF oracle exceeds this fraction of the "
                  "brightest emission (default 1e-5)"},
    {"light_samples", "samples per element of each point, distant, dome or sphere light (default 16)"},
    {"interpolate", "1: radiosity interpolated from the element vertices; 0: constant per element (default 1 for "
                    "radiosity's display, 0 for hybrid's gather)"},
    {"solver", "0: progressive refinement, Southwell shooting; 1: hierarchical, BF-refined links; 2: stochastic, "
               "shooting by ray casting (no form factors: for 10^5 triangles and more; carries light across mirrors "
               "and glass); default: stochastic above 4096 elements or with mirrors or glass, else progressive"},
    {"rays_per_element", "stochastic solver: rays of the first shot per element; later shots in proportion to the "
                         "power left unshot (default 1024)"},
    {"refine_levels", "adaptive meshing: rounds of halving the cells where the radiosity varies fast (an element "
                      "differs from one of its display vertices by more than refine_tolerance of the larger, or "
                      "direct_tolerance's test), each followed by a new solve; 0 to 3, not with solver 1 (not given: "
                      "3 rounds by direct_tolerance's test alone, one solve, at most 8192 elements)"},
    {"refine_tolerance", "adaptive meshing's threshold, relative to the local radiosity and at least a tenth of the "
                         "mean (default 0.1)"},
    {"direct_tolerance", "adaptive meshing: also split an element whose display, interpolated to its centroid, "
                         "misses the direct light evaluated there by more than this fraction (default 0.005; 0: off)"},
    {"time_slices", "with motion blur, the shutter's slices: one solution per slice, at its middle instant, "
                    "read by the camera samples in it (default 8; 1 to 255)"},
    };
    return params;
}

RadiositySettings RadiositySettingsFrom(const IntegratorSettings& s, const Scene& scene, const char* who) {
    RadiositySettings r;
    r.element_size = s.Param("element_size", kDefaultElementOfDiameter * 2.f * scene.scene_radius());
    if (!(r.element_size > 0.f) || !std::isfinite(r.element_size))
        throw std::invalid_argument(std::string(who) + " element_size must be a finite number > 0");
    const float solver = s.Param("solver", -1.f);
    if (solver != -1.f && solver != 0.f && solver != 1.f && solver != 2.f)
        throw std::invalid_argument(std::string(who) +
                                    " solver must be 0 (progressive), 1 (hierarchical) or 2 (stochastic)");
    r.solver = solver == -1.f ? RadiositySolver::kAuto : RadiositySolver(int(solver) + 1);
    const bool hierarchical = r.solver == RadiositySolver::kHierarchical;
    // The tolerances mean different things; each default is where the solver agrees with
    // the progressive one within 1 % per wall on the Cornell box (docs/integrators.md).
    r.tolerance = s.Param("tolerance", hierarchical ? 1e-5f : 1e-3f);
    if (!(r.tolerance > 0.f && r.tolerance < 1.f))
        throw std::invalid_argument(std::string(who) + " tolerance must be a number in (0, 1)");
    const float samples = s.Param("light_samples", 16.f);
    if (!(samples >= 1.f && samples <= 65536.f && samples == std::floor(samples)))
        throw std::invalid_argument(std::string(who) + " light_samples must be a whole number from 1 to 65536");
    r.light_samples = uint32_t(samples);
    r.rays_per_element = s.Param("rays_per_element", r.rays_per_element);
    if (!(r.rays_per_element >= 1.f && r.rays_per_element <= 1e6f))
        throw std::invalid_argument(std::string(who) + " rays_per_element must be a number from 1 to 1e6");
    // Refined by default (issue 46: a lit plane's point error under 2 % without choosing an
    // element size); the hierarchical solver refines its own links instead.
    const float levels = s.Param("refine_levels", hierarchical ? 0.f : float(kDefaultRefineLevels));
    if (!(levels >= 0.f && levels <= float(RadiosityMesh::kMaxDepth) && levels == std::floor(levels)))
        throw std::invalid_argument(std::string(who) + " refine_levels must be a whole number from 0 to " +
                                    std::to_string(RadiosityMesh::kMaxDepth));
    r.refine_levels = uint32_t(levels);
    // The default refines by the direct light's interpolation error, up to
    // kDefaultRefineBudget elements (a mesh already that large, the Cornell teapot's 196k,
    // is not refined unless asked to be).
    if (!s.params.count("refine_levels") && r.refine_levels > 0) {
        r.refine_by_direct = true;
        // The progressive solver, asked for by name, pays for every element pair: its
        // default refinement stops where the automatic choice would leave it.
        r.refine_budget = r.solver == RadiositySolver::kProgressive ? RadiositySettings::kAutoStochasticElements
                                                                     : kDefaultRefineBudget;
    }
    if (r.refine_levels > 0 && r.solver == RadiositySolver::kHierarchical)
        throw std::invalid_argument(std::string(who) + " refine_levels needs solver 0 (progressive) or 2 (stochastic): "
                                                       "the hierarchical solver refines its own links");
    r.refine_tolerance = s.Param("refine_tolerance", r.refine_tolerance);
    if (!(r.refine_tolerance > 0.f && r.refine_tolerance < 10.f))
        throw std::invalid_argument(std::string(who) + " refine_tolerance must be a number in (0, 10)");
    r.direct_tolerance = s.Param("direct_tolerance", r.direct_tolerance);
    if (!(r.direct_tolerance >= 0.f && r.direct_tolerance < 10.f))
        throw std::invalid_argument(std::string(who) + " direct_tolerance must be a number in [0, 10)");
    r.time_slices = TimeSlicesSetting(s, who, 8.f);
    return r;
}

bool RadiosityInterpolates(const IntegratorSettings& s, const char* who, bool by_default) {
    const float v = s.Param("interpolate", by_default ? 1.f : 0.f);
    if (v != 0.f && v != 1.f) throw std::invalid_argument(std::string(who) + " interpolate must be 0 or 1");
    return v == 1.f;
}

namespace {

RadiositySolution SolveOn(const Scene& scene, const RadiosityMesh& mesh, const RadiositySettings& settings) {
    RadiositySolver solver = settings.solver;
    if (solver == RadiositySolver::kAuto && settings.refine_by_direct && mesh.refined()) {
        // The default's refined mesh: shooting by rays, as many as the uniform mesh would
        // take (rays_per_element per cell), so refining does not multiply the solve's cost.
        // The display's direct light, where the refinement is, is evaluated at points; what
        // the elements hold is the smooth interreflection, averaged at the vertices. (The
        // progressive solver's pairs grow with the square: 41 s on the Cornell box refined
        // once, 3448 elements.)
        RadiositySettings s = settings;
        s.first_rays = double(settings.rays_per_element) * double(mesh.num_cells());
        return SolveStochastic(scene, mesh, s);
    }
    if (solver == RadiositySolver::kAuto)
        solver = mesh.elements().size() > RadiositySettings::kAutoStochasticElements || scene.has_delta_surfaces()
                     ? RadiositySolver::kStochastic
                     : RadiositySolver::kProgressive;
    return solver == RadiositySolver::kHierarchical ? SolveHierarchical(scene, mesh, settings)
           : solver == RadiositySolver::kStochastic ? SolveStochastic(scene, mesh, settings)
                                                     : SolveProgressive(scene, mesh, settings);
}

// One slice's block: the mesh and solution at settings.shutter_time.
void AppendSlice(const Scene& scene, const RadiositySettings& settings, std::string* out) {
    const SolvedRadiosity solved = SolveRadiosity(scene, settings);
    const RadiosityMesh& mesh = *solved.mesh;
    const RadiositySolution& sol = solved.solution;
    const std::vector<Color> reflected = ReflectedRadiosity(mesh, sol);
    Header h{};
    std::memcpy(h.magic, kSliceMagic, 4);
    h.elements = uint32_t(mesh.elements().size());
    h.vertices = uint32_t(mesh.num_vertices());
    h.shots = sol.shots;
    h.relative_residual = sol.entered_power > 0.0 && !sol.residual.empty() ? float(sol.residual.back() / sol.entered_power) : 0.f;
    h.converged = sol.converged;
    h.cells = uint32_t(mesh.num_cells());
    h.depth_bytes = mesh.refined() ? h.elements : 0;
    const size_t at = out->size();
    out->resize(at + sizeof(Header) + h.depth_bytes);
    std::memcpy(out->data() + at, &h, sizeof(Header));
    if (h.depth_bytes) std::memcpy(out->data() + at + sizeof(Header), mesh.leaf_depth().data(), h.depth_bytes);
    Append(out, reflected);
    Append(out, sol.direct);
    if (solved.vertex_direct.empty()) {
        Append(out, mesh.VertexAverage(reflected));
        Append(out, mesh.VertexAverage(sol.direct));
        return;
    }
    // The display: the direct part evaluated at the vertex, the interreflected rest (smooth)
    // the area-weighted mean of the elements there.
    std::vector<Color> indirect(reflected.size());
    for (size_t k = 0; k < reflected.size(); ++k) {
        const Color i = reflected[k] - sol.direct[k];
        indirect[k] = Color(std::max(0.f, i.x), std::max(0.f, i.y), std::max(0.f, i.z));
    }
    std::vector<Color> vertex = mesh.VertexAverage(indirect);
    for (size_t k = 0; k < vertex.size(); ++k) vertex[k] += solved.vertex_direct[k];
    Append(out, vertex);
    Append(out, solved.vertex_direct);
}

}  // namespace

std::vector<uint8_t> RefinedDepths(const RadiosityMesh& mesh, const RadiositySolution& solution, float tolerance,
                                   const std::vector<Color>* point_direct, const std::vector<Color>* centroid_direct,
                                   float direct_tolerance) {
    const std::vector<RadiosityElement>& el = mesh.elements();
    const std::vector<Color> reflected = ReflectedRadiosity(mesh, solution);
    const std::vector<Color> vertex = mesh.VertexAverage(reflected);
    const std::vector<Color> vertex_direct = mesh.VertexAverage(solution.direct);
    double sum = 0.0, area = 0.0;
    for (size_t k = 0; k < reflected.size(); ++k) {
        const float b = Luminance(reflected[k]);
        if (b > 0.f) sum += double(b) * el[k / 2].area, area += el[k / 2].area;
    }
    if (!(area > 0.0)) return {};
    // Relative to the local radiosity, so a shadow's edge counts in a dim room as in a bright
    // one, but not below a tenth of the mean, where the solvers' noise would drive it.
    const float floor = float(0.1 * sum / area);
    // The interpolation test: relative to the local direct light, down to a hundredth of
    // its mean (a plane's far corners under a small light get a few percent of its peak).
    const bool by_points = direct_tolerance > 0.f && point_direct && centroid_direct &&
                           point_direct->size() == 2 * mesh.num_vertices() && centroid_direct->size() == reflected.size();
    float direct_floor = 0.f;
    if (by_points) {
        double dsum = 0.0, darea = 0.0;
        for (size_t k = 0; k < centroid_direct->size(); ++k) {
            const float b = Luminance((*centroid_direct)[k]);
            if (b > 0.f) dsum += double(b) * el[k / 2].area, darea += el[k / 2].area;
        }
        direct_floor = darea > 0.0 ? float(0.01 * dsum / darea) : 0.f;
    }
    std::vector<uint8_t> depth;
    depth.reserve(el.size());
    bool changed = false;
    for (size_t e = 0; e < el.size(); ++e) {
        const uint8_t d = mesh.refined() ? mesh.leaf_depth()[e] : 0;
        bool split = false;
        for (int side = 0; side < 2 && !split && d < RadiosityMesh::kMaxDepth && el[e].emitter == Scene::kNoEmitter;
             ++side) {
            const float b = Luminance(reflected[2 * e + side]), bd = Luminance(solution.direct[2 * e + side]);
            for (int k = 0; k < 3; ++k) {
                const uint32_t vk = 2 * el[e].vertex[k] + side;
                const float v = Luminance(vertex[vk]), vd = Luminance(vertex_direct[vk]);
                // With the direct part evaluated at points, its own test below judges it; this
                // one then looks at the interreflected rest only.
                const float step = by_points ? std::abs((v - vd) - (b - bd))
                                             : std::max(std::abs(v - b), std::abs(vd - bd));
                if (step > tolerance * std::max({b, v, floor})) split = true;
            }
            if (by_points && !split) {
                float interpolated = 0.f;
                for (int k = 0; k < 3; ++k) interpolated += Luminance((*point_direct)[2 * el[e].vertex[k] + side]) / 3.f;
                const float exact = Luminance((*centroid_direct)[2 * e + side]);
                if (std::abs(interpolated - exact) > direct_tolerance * std::max({exact, interpolated, direct_floor}))
                    split = true;
            }
        }
        if (split) {
            depth.insert(depth.end(), 4, uint8_t(d + 1));
            changed = true;
        } else {
            depth.push_back(d);
        }
        if (depth.size() > RadiosityMesh::kMaxElements) return {};
    }
    return changed ? depth : std::vector<uint8_t>{};
}

std::vector<uint8_t> DirectRefinedDepths(const RadiosityMesh& mesh, const std::vector<Color>& vertex_direct,
                                         const std::vector<Color>& centroid_direct, float tolerance, size_t budget) {
    const std::vector<RadiosityElement>& el = mesh.elements();
    if (!(tolerance > 0.f) || vertex_direct.size() != 2 * mesh.num_vertices() || centroid_direct.size() != 2 * el.size())
        return {};
    double sum = 0.0, area = 0.0;
    for (size_t k = 0; k < centroid_direct.size(); ++k) {
        const float b = Luminance(centroid_direct[k]);
        if (b > 0.f) sum += double(b) * el[k / 2].area, area += el[k / 2].area;
    }
    if (!(area > 0.0)) return {};
    // Relative to the local direct light, down to a hundredth of its mean (a plane's far
    // corners under a small light get a few percent of its peak).
    const float floor = float(0.01 * sum / area);
    // Each element's interpolation error over what the tolerance allows; > 1: split.
    std::vector<std::pair<float, uint32_t>> over;
    for (size_t e = 0; e < el.size(); ++e) {
        const uint8_t d = mesh.refined() ? mesh.leaf_depth()[e] : 0;
        if (d >= RadiosityMesh::kMaxDepth || el[e].emitter != Scene::kNoEmitter) continue;
        float worst = 0.f;
        for (int side = 0; side < 2; ++side) {
            float interpolated = 0.f;
            for (int k = 0; k < 3; ++k) interpolated += Luminance(vertex_direct[2 * el[e].vertex[k] + side]) / 3.f;
            const float exact = Luminance(centroid_direct[2 * e + side]);
            worst = std::max(worst, std::abs(interpolated - exact) / (tolerance * std::max({exact, interpolated, floor})));
        }
        if (worst > 1.f) over.push_back({worst, uint32_t(e)});
    }
    if (over.empty() || el.size() + 3 >= budget) return {};
    // Within the budget, the largest errors first (ties by index: the same mesh on every worker).
    const size_t room = (budget - el.size()) / 3;
    if (over.size() > room) {
        std::sort(over.begin(), over.end(), [](const auto& a, const auto& b) {
            return a.first != b.first ? a.first > b.first : a.second < b.second;
        });
        over.resize(room);
    }
    if (over.empty()) return {};
    std::vector<uint8_t> split(el.size(), 0);
    for (const auto& o : over) split[o.second] = 1;
    std::vector<uint8_t> depth;
    depth.reserve(el.size() + 3 * over.size());
    for (size_t e = 0; e < el.size(); ++e) {
        const uint8_t d = mesh.refined() ? mesh.leaf_depth()[e] : 0;
        if (split[e]) depth.insert(depth.end(), 4, uint8_t(d + 1));
        else depth.push_back(d);
    }
    return depth;
}

SolvedRadiosity SolveRadiosity(const Scene& scene, const RadiositySettings& settings) {
    const ShutterTimeScope instant(settings.shutter_time);  // the mesh and the calling thread's rays
    tbb::task_arena arena(settings.threads > 0 ? settings.threads : tbb::this_task_arena::max_concurrency());
    SolvedRadiosity out;
    out.mesh = std::make_unique<RadiosityMesh>(scene, settings.element_size);
    if (settings.refine_by_direct) {
        // The default: the mesh is refined where the display's direct light, interpolated
        // from the vertices, misses the value evaluated at the element's centroid; both are
        // point evaluations, so no solve is needed between rounds.
        bool settled = false;
        for (uint32_t level = 0; level < settings.refine_levels; ++level) {
            out.vertex_direct = VertexPointDirect(scene, *out.mesh, settings, arena);
            if (out.vertex_direct.empty()) break;
            if (out.mesh->elements().size() + 3 >= settings.refine_budget) {  // no room: skip the centroids
                settled = true;
                break;
            }
            const std::vector<Color> centroid = CentroidPointDirect(scene, *out.mesh, settings, arena);
            std::vector<uint8_t> depth = DirectRefinedDepths(*out.mesh, out.vertex_direct, centroid,
                                                             settings.direct_tolerance, settings.refine_budget);
            if (depth.empty()) {
                settled = true;
                break;
            }
            out.mesh = std::make_unique<RadiosityMesh>(scene, settings.element_size, depth);
        }
        out.solution = SolveOn(scene, *out.mesh, settings);
        if (!settled) out.vertex_direct = VertexPointDirect(scene, *out.mesh, settings, arena);
        return out;
    }
    out.solution = SolveOn(scene, *out.mesh, settings);
    out.vertex_direct = VertexPointDirect(scene, *out.mesh, settings, arena);
    for (uint32_t level = 0; level < settings.refine_levels; ++level) {
        std::vector<Color> centroid_direct;
        if (settings.direct_tolerance > 0.f && !out.vertex_direct.empty())
            centroid_direct = CentroidPointDirect(scene, *out.mesh, settings, arena);
        std::vector<uint8_t> depth = RefinedDepths(*out.mesh, out.solution, settings.refine_tolerance,
                                                   &out.vertex_direct, &centroid_direct, settings.direct_tolerance);
        if (depth.empty() || depth.size() > settings.refine_budget) break;
        out.mesh = std::make_unique<RadiosityMesh>(scene, settings.element_size, depth);
        out.solution = SolveOn(scene, *out.mesh, settings);
        out.vertex_direct = VertexPointDirect(scene, *out.mesh, settings, arena);
    }
    return out;
}

std::string SolveRadiosityProduct(const Scene& scene, const RadiositySettings& settings) {
    OuterHeader outer{};
    std::memcpy(outer.magic, kMagic, 4);
    outer.time_slices = scene.has_motion() ? settings.time_slices : 1;
    std::string out(sizeof(OuterHeader), '\0');
    std::memcpy(out.data(), &outer, sizeof(OuterHeader));
    for (uint32_t k = 0; k < outer.time_slices; ++k) {
        RadiositySettings at = settings;
        at.shutter_time = ShutterSlices{outer.time_slices}.Middle(k);
        AppendSlice(scene, at, &out);
    }
    return out;
}

namespace {

// Every tile builds its integrator, and the preview renders a frame as one tile: without
// this, each would rebuild the mesh and re-parse the product (most of a preview frame's
// time). The last few (scene, element size, product) are kept; the product's bytes are
// compared whole, so a different solution is never taken for a cached one.
struct CachedLookup {
    const Scene* scene;
    size_t triangles;
    float element_size;
    std::string product;
    std::shared_ptr<const RadiosityLookup::Slices> data;
};
std::mutex cache_mutex;
std::vector<CachedLookup> cache;
constexpr size_t kCachedLookups = 4;

std::shared_ptr<const RadiosityLookup::Slices> Parse(const Scene& scene, float element_size,
                                                     const std::string& product, const char* who) {
    OuterHeader outer;
    if (product.size() < sizeof(OuterHeader) || std::memcmp(product.data(), kMagic, 4) != 0)
        throw std::invalid_argument(std::string(who) + ": the scene product is not a radiosity solution");
    std::memcpy(&outer, product.data(), sizeof(OuterHeader));
    if (outer.time_slices < 1 || outer.time_slices > kMaxShutterSlices || (outer.time_slices > 1 && !scene.has_motion()))
        throw std::invalid_argument(std::string(who) + ": the scene product's time slices do not fit the scene");
    auto slices = std::make_shared<RadiosityLookup::Slices>();
    size_t at = sizeof(OuterHeader);
    for (uint32_t k = 0; k < outer.time_slices; ++k) {
        Header h;
        if (product.size() - at < sizeof(Header) || std::memcmp(product.data() + at, kSliceMagic, 4) != 0)
            throw std::invalid_argument(std::string(who) + ": the scene product is truncated");
        std::memcpy(&h, product.data() + at, sizeof(Header));
        const ShutterTimeScope instant(ShutterSlices{outer.time_slices}.Middle(k));  // the slice's own mesh
        const size_t ne = 2 * size_t(h.elements), nv = 2 * size_t(h.vertices);
        const size_t bytes = sizeof(Header) + h.depth_bytes + (2 * ne + 2 * nv) * sizeof(Color);
        if (product.size() - at < bytes) throw std::invalid_argument(std::string(who) + ": the scene product is truncated");
        std::vector<uint8_t> depth(h.depth_bytes);
        if (h.depth_bytes) std::memcpy(depth.data(), product.data() + at + sizeof(Header), h.depth_bytes);
        std::unique_ptr<RadiosityLookup::Data> data;
        try {
            data = std::make_unique<RadiosityLookup::Data>(scene, element_size, depth);
        } catch (const std::invalid_argument&) {
            data.reset();  // refinement depths of another mesh
        }
        if (!data || h.elements != data->mesh.elements().size() || h.vertices != data->mesh.num_vertices() ||
            h.cells != data->mesh.num_cells())
            throw std::invalid_argument(std::string(who) +
                                        ": the scene product is a radiosity solution of another scene or element_size");
        const char* p = product.data() + at + sizeof(Header) + h.depth_bytes;
        auto read = [&](std::vector<Color>* v, size_t count) {
            v->resize(count);
            if (count) std::memcpy(v->data(), p, count * sizeof(Color));
            p += count * sizeof(Color);
        };
        read(&data->element_reflected, ne);
        read(&data->element_direct, ne);
        read(&data->vertex_reflected, nv);
        read(&data->vertex_direct, nv);
        at += bytes;
        slices->push_back(std::move(data));
    }
    if (at != product.size()) throw std::invalid_argument(std::string(who) + ": the scene product has trailing bytes");
    return slices;
}

}  // namespace

RadiosityLookup::RadiosityLookup(const Scene& scene, float element_size, const std::string& product,
                                 bool interpolate, const char* who)
    : interpolate_(interpolate) {
    {
        std::lock_guard<std::mutex> lock(cache_mutex);
        for (const CachedLookup& c : cache)
            if (c.scene == &scene && c.triangles == scene.num_triangles() && c.element_size == element_size &&
                c.product == product) {
                data_ = c.data;
                return;
            }
    }
    data_ = Parse(scene, element_size, product, who);
    std::lock_guard<std::mutex> lock(cache_mutex);
    if (cache.size() >= kCachedLookups) cache.erase(cache.begin());
    cache.push_back({&scene, scene.num_triangles(), element_size, product, data_});
}

bool RadiosityLookup::Reflected(const SurfaceHit& hit, Vec3 wo, Color* reflected, Color* direct) const {
    float w[3];
    const Data& d = *(*data_)[ShutterSlices{uint32_t(data_->size())}.Current()];
    const int32_t e = d.mesh.Locate(hit, w);
    if (e < 0) return false;
    const RadiosityElement& el = d.mesh.elements()[e];
    const int side = Dot(wo, el.n) > 0.f ? 0 : 1;
    if (!interpolate_) {
        *reflected = d.element_reflected[2 * e + side];
        *direct = d.element_direct[2 * e + side];
        return true;
    }
    Color r(0.f), dir(0.f);
    for (int k = 0; k < 3; ++k) {
        r += d.vertex_reflected[2 * el.vertex[k] + side] * w[k];
        dir += d.vertex_direct[2 * el.vertex[k] + side] * w[k];
    }
    *reflected = r;
    *direct = dir;
    return true;
}

}  // namespace tessera
