// Scene queries about emitters: which emitter a hit is, what it emits, and sampling and
// densities of emission for next event estimation and light paths. Each query dispatches
// on the emitter's kind to EmitterOf<Kind> in the kind's own file (lights/, listed in
// light_kinds.h); the Scene's list of emitters is built in scene.cpp.
#include "scene.h"

#include <algorithm>

#include <cstring>
#include <stdexcept>
#include <string>
#include <limits>

#include "ray_counters.h"
#include "sampling.h"

namespace tessera {

int32_t Scene::EmitterAt(const SurfaceHit& hit) const {
    if constexpr (!kFullFeatures) return meshes_[0].emitter[hit.prim_id];
    if (hit.geom_id == kCurveGeometry) return kNoEmitter;  // emissive curves come as triangle tubes
    if (hit.geom_id != kTriangleGeometry) return sphere_emitter_[hit.prim_id];
    const int32_t local = meshes_[hit.mesh].emitter[hit.prim_id];
    if (hit.instance == kNoInstance || local < 0) return local;
    return instances_[hit.instance].emitter_base + local;
}

Color Scene::Emitted(int32_t emitter, const SurfaceHit& hit, Vec3 wo) const {
    if (emitter < 0) return Color(0.f);
    const Emitter& e = emitters_[emitter];
    if (kFullFeatures && e.kind == kKindOf<SphereLight>) return lights_.Of<SphereLight>()[e.index].radiance;
    const Material& m = MaterialOf(e.mesh, e.index);
    if (!m.two_sided_emission && !(Dot(hit.ng, wo) > 0.f)) return Color(0.f);
    const Color Le = TriangleEmission(e.mesh, e.index, hit.b1, hit.b2);
    return !kFullFeatures || m.emission_shaping < 0 ? Le : Le * EmissionShaping(m, Dot(hit.ng, wo) >= 0.f ? hit.ng : -hit.ng, wo);
}

TriangleLight Scene::TriangleLightOf(const Emitter& e) const {
    if (!still_triangle_lights_.empty()) return still_triangle_lights_[size_t(&e - emitters_.data())];
    return ResolveTriangleLight(e);
}

TriangleLight Scene::ResolveTriangleLight(const Emitter& e) const {
    TriangleLight t;
    Vec3 tri[3];
    t.orientation = TriangleVertices(e.mesh, e.index, e.instance, tri);
    t.p0 = tri[0];
    t.p1 = tri[1];
    t.p2 = tri[2];
    t.area = EmitterArea(e);
    t.two_sided = MaterialOf(e.mesh, e.index).two_sided_emission;
    t.instanced = kFullFeatures && e.instance != kNoInstance;
    return t;
}

bool Scene::SampleEmitter(uint32_t emitter, Vec3 ref, Vec2 u, LightSample* out) const {
    const Emitter& e = emitters_[emitter];
    out->is_delta = false;
    if constexpr (!kFullFeatures)
        return TriangleLightOf(e).Sample(
            ref, u, [&](float b1, float b2) { return TriangleEmission(e.mesh, e.index, b1, b2); }, out);
    return VisitLightKind(e.kind, [&](auto kind) {
        return EmitterOf<typename decltype(kind)::type>::Sample(*this, e, ref, u, out);
    });
}

bool Scene::SampleEmission(uint32_t emitter, Vec2 u_pos, Vec2 u_dir, float u_side, EmissionSample* out) const {
    const Emitter& e = emitters_[emitter];
    out->on_surface = false;
    return VisitLightKind(e.kind, [&](auto kind) {
        return EmitterOf<typename decltype(kind)::type>::SampleEmission(*this, e, u_pos, u_dir, u_side, out);
    });
}

float Scene::EmissionPdfDirection(uint32_t emitter, Vec3 n, Vec3 w) const {
    const Emitter& e = emitters_[emitter];
    return VisitLightKind(e.kind, [&](auto kind) {
        return EmitterOf<typename decltype(kind)::type>::PdfDirection(*this, e, n, w);
    });
}

bool Scene::EmissionToward(uint32_t emitter, const EmissionSample& es, Vec3 w, Color* Le_cos, float* pdf_dir) const {
    const Emitter& e = emitters_[emitter];
    *Le_cos = Color(0.f);
    *pdf_dir = 0.f;
    return VisitLightKind(e.kind, [&](auto kind) {
        return EmitterOf<typename decltype(kind)::type>::EmissionToward(*this, e, es, w, Le_cos, pdf_dir);
    });
}

float Scene::EmissionPdfPosition(uint32_t emitter) const {
    const Emitter& e = emitters_[emitter];
    return VisitLightKind(e.kind, [&](auto kind) { return EmitterOf<typename decltype(kind)::type>::PdfPosition(*this, e); });
}

float Scene::InfiniteLightDensity(Vec3 p, Vec3 w) const {
    float pdf = 0.f;
    for (uint32_t i : environment_lights_) {
        float density = 0.f;
        EnvironmentRadiance(emitters_[i], p, w, &density);
        pdf += light_sampler_.Pmf(i) * density;
    }
    return pdf;
}

bool Scene::IsInfiniteLight(uint32_t emitter) const {
    const Emitter& e = emitters_[emitter];
    return VisitLightKind(e.kind, [&](auto kind) { return EmitterOf<typename decltype(kind)::type>::Infinite(e); });
}

bool Scene::IsDeltaLight(uint32_t emitter) const {
    const Emitter& e = emitters_[emitter];
    return VisitLightKind(e.kind, [&](auto kind) { return EmitterOf<typename decltype(kind)::type>::Delta(e); });
}

Color Scene::EnvironmentRadiance(const Emitter& e, Vec3 origin, Vec3 dir, float* pdf) const {
    return VisitLightKind(e.kind, [&](auto kind) {
        return EmitterOf<typename decltype(kind)::type>::Environment(*this, e, origin, dir, pdf);
    });
}

float Scene::EmitterPdf(uint32_t emitter, Vec3 ref, const SurfaceHit& hit) const {
    const Emitter& e = emitters_[emitter];
    if (kFullFeatures && e.kind == kKindOf<SphereLight>) return SphereAt(e.index).Pdf(ref);
    return TriangleLightPdf(ref, hit.p, hit.ng, EmitterArea(e));
}

float Scene::EmitterArea(const Emitter& e) const {
    const bool reshaped = kFullFeatures && has_motion() && e.kind == kKindOf<TriangleLight> &&
                          (meshes_[e.mesh].time_steps > 1 ||
                           (e.instance != kNoInstance && instances_[e.instance].time_steps > 1));
    if (!reshaped) return e.area;
    // A moving instance may scale its triangles, a deforming mesh reshape them: the area now.
    Vec3 p[3];
    TriangleVertices(e.mesh, e.index, e.instance, p);
    return std::max(1e-30f, 0.5f * Length(Cross(p[1] - p[0], p[2] - p[0])));
}


void Scene::BuildLightBVH(const std::vector<double>& power, SceneDesc::LightSelection selection) {
    if (selection == SceneDesc::LightSelection::kPower) return;
    // Still triangles only: a moving or deforming emitter's bounds would hold at one instant.
    auto still = [&](const Emitter& e) {
        return e.kind == kKindOf<TriangleLight> && meshes_[e.mesh].time_steps <= 1 &&
               (e.instance == kNoInstance || instances_[e.instance].time_steps <= 1);
    };
    std::vector<LightBounds> bounds;
    std::vector<uint32_t> ids;
    double bvh_power = 0.0, total = 0.0;
    for (uint32_t i = 0; i < emitters_.size(); ++i) {
        total += power[i];
        if (!still(emitters_[i]) || !(power[i] > 0.0)) continue;
        // A linked light stays out: the BVH is shared by every link group (BuildGroupLights).
        if (!emitter_link_.empty() && emitter_link_[i] >= 0) continue;
        const Emitter& e = emitters_[i];
        Vec3 p[3];
        const float orientation = TriangleVertices(e.mesh, e.index, e.instance, p);
        if (orientation < 0.f) std::swap(p[1], p[2]);  // the side it faces: Cross(p1 - p0, p2 - p0) x orientation
        const LightBounds b = LightBounds::Triangle(p, float(power[i]), MaterialOf(e.mesh, e.index).two_sided_emission);
        if (!(b.phi > 0.f)) continue;
        bounds.push_back(b);
        ids.push_back(i);
        bvh_power += power[i];
    }
    const size_t needed = selection == SceneDesc::LightSelection::kBVH ? 1 : kMinLightBVHEmitters;
    if (ids.size() < needed || !(total > 0.0)) return;
    light_bvh_ = BVHLightSampler(bounds, ids, emitters_.size());
    light_bvh_share_ = float(bvh_power / total);
    std::vector<double> other_power;
    other_light_index_.assign(emitters_.size(), -1);
    std::vector<uint8_t> in_bvh(emitters_.size(), 0);
    for (uint32_t id : ids) in_bvh[id] = 1;
    for (uint32_t i = 0; i < emitters_.size(); ++i) {
        if (in_bvh[i]) continue;
        other_light_index_[i] = int32_t(other_light_ids_.size());
        other_light_ids_.push_back(i);
        other_power.push_back(power[i]);
    }
    // With nothing else (or nothing else with power) the BVH takes every sample.
    other_lights_ = LightSampler(other_power);
    if (other_lights_.empty()) light_bvh_share_ = 1.f;
}

bool Scene::SampleAnyLight(float u, Vec3 p, Vec3 n, uint32_t* light, float* pmf) const {
    if (light_bvh_.empty()) {
        *light = light_sampler_.Sample(u, pmf);
        return true;
    }
    return SampleBVHOrTable(u, p, n, light_bvh_share_, other_lights_, light, pmf);
}

bool Scene::SampleBVHOrTable(float u, Vec3 p, Vec3 n, float share, const LightSampler& other, uint32_t* light,
                             float* pmf) const {
    if (u < share) {
        const float ub = std::min(u / share, 0x1.fffffep-1f);
        if (!light_bvh_.Sample(ub, p, n, light, pmf)) return false;
        *pmf *= share;
        return true;
    }
    const float uo = std::min((u - share) / (1.f - share), 0x1.fffffep-1f);
    float other_pmf = 0.f;
    *light = other_light_ids_[other.Sample(uo, &other_pmf)];
    *pmf = other_pmf * (1.f - share);
    return true;
}

float Scene::AnyLightPmf(Vec3 p, Vec3 n, uint32_t light) const {
    if (light_bvh_.empty()) return light_sampler_.Pmf(light);
    if (light >= other_light_index_.size()) return 0.f;
    const int32_t o = other_light_index_[light];
    if (o < 0) return light_bvh_share_ * light_bvh_.Pmf(p, n, light);
    return (1.f - light_bvh_share_) * other_lights_.Pmf(uint32_t(o));
}

}  // namespace tessera

namespace tessera {

void Scene::BuildLightLinks(const SceneDesc& desc) {
    light_links_ = desc.light_links;
    const uint32_t groups = light_links_.num_groups();
    for (size_t m = 0; m < materials_.size(); ++m) {
        if (materials_[m].link_group != 0 && materials_[m].link_group >= groups)
            throw std::invalid_argument("material " + std::to_string(m) + " has link group " +
                                        std::to_string(materials_[m].link_group) + " of " + std::to_string(groups));
        light_links_.Check(materials_[m].light_link, "material " + std::to_string(m));
    }
    auto check = [&](const std::vector<int32_t>& links, size_t lights, const char* what) {
        if (links.size() > lights)
            throw std::invalid_argument(std::string("more ") + what + " light links than " + what + " lights");
        for (size_t i = 0; i < links.size(); ++i)
            light_links_.Check(links[i], std::string(what) + " light " + std::to_string(i));
    };
    check(desc.sphere_light_link, desc.sphere_lights.size(), "sphere");
    check(desc.point_light_link, desc.point_lights.size(), "point");
    check(desc.distant_light_link, desc.distant_lights.size(), "distant");
    light_links_.Check(desc.dome_light_link, "the dome");
    // Lights added after translation (default lighting) have no entry: the default link.
    auto link_of = [](const std::vector<int32_t>& links, uint32_t i) { return i < links.size() ? links[i] : -1; };
    emitter_link_.assign(emitters_.size(), -1);
    std::vector<uint8_t> used(light_links_.num_links(), 0);
    for (size_t i = 0; i < emitters_.size(); ++i) {
        const Emitter& e = emitters_[i];
        int32_t link = -1;
        if (e.kind == kKindOf<TriangleLight>) link = MaterialOf(e.mesh, e.index).light_link;
        else if (e.kind == kKindOf<SphereLight>) link = link_of(desc.sphere_light_link, e.index);
        else if (e.kind == kKindOf<PointLight>) link = link_of(desc.point_light_link, e.index);
        else if (e.kind == kKindOf<DistantLight>) link = link_of(desc.distant_light_link, e.index);
        else if (e.kind == kKindOf<DomeLight>) link = desc.dome_light_link;
        emitter_link_[i] = link;
        if (link >= 0) used[size_t(link)] = 1;
    }
    for (uint8_t u : used) num_linked_lights_ += u;
    has_light_links_ = num_linked_lights_ > 0;
    if (!has_light_links_) emitter_link_.clear();
}

void Scene::BuildGroupLights(const std::vector<double>& power) {
    double bvh_power = 0.0;
    if (!light_bvh_.empty())
        for (uint32_t i = 0; i < emitters_.size(); ++i)
            if (other_light_index_[i] < 0) bvh_power += power[i];
    group_lights_.resize(std::max(1u, light_links_.num_groups()));
    std::vector<double> group_power(emitters_.size());
    for (uint32_t g = 0; g < group_lights_.size(); ++g) {
        for (uint32_t i = 0; i < emitters_.size(); ++i) group_power[i] = Illuminates(i, g) ? power[i] : 0.0;
        LinkGroupLights& gl = group_lights_[g];
        if (light_bvh_.empty()) {
            gl.all = LightSampler(group_power);
            continue;
        }
        std::vector<double> other_power;
        double other = 0.0;
        for (uint32_t id : other_light_ids_) {
            other_power.push_back(group_power[id]);
            other += group_power[id];
        }
        gl.other = LightSampler(other_power);
        gl.bvh_share = gl.other.empty() ? 1.f : float(bvh_power / (bvh_power + other));
    }
}

bool Scene::SampleLinkedLight(float u, Vec3 p, Vec3 n, uint32_t* light, float* pmf, uint32_t group) const {
    const LinkGroupLights& gl = group_lights_[group];
    if (light_bvh_.empty()) {
        if (gl.all.empty()) return false;  // no light illuminates the group
        *light = gl.all.Sample(u, pmf);
        return true;
    }
    return SampleBVHOrTable(u, p, n, gl.bvh_share, gl.other, light, pmf);
}

float Scene::LinkedLightPmf(Vec3 p, Vec3 n, uint32_t light, uint32_t group) const {
    const LinkGroupLights& gl = group_lights_[group];
    if (light_bvh_.empty()) return gl.all.Pmf(light);
    if (light >= other_light_index_.size()) return 0.f;
    const int32_t o = other_light_index_[light];
    if (o < 0) return gl.bvh_share * light_bvh_.Pmf(p, n, light);
    return (1.f - gl.bvh_share) * gl.other.Pmf(uint32_t(o));
}

}  // namespace tessera
