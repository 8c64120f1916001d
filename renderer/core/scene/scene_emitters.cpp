// Scene queries about emitters: which emitter a hit is, what it emits, and sampling and
// densities of emission for next event estimation and light paths (the light kinds are
// in lights/; the Scene's list of emitters is built in scene.cpp).
#include "scene.h"

#include <algorithm>

#include <cstring>
#include <limits>

#include "ray_counters.h"
#include "sampling.h"

namespace tessera {

namespace {

// A light at this thread's shutter time: maps between the world and the light as the
// scene describes it (identity for a light that stands still).
struct LightFrame {
    const float* m = nullptr;
    float m_scratch[12], n[9];
    Vec3 ToWorldDir(Vec3 d) const { return m ? Normalize(TransformVector(m, d)) : d; }
    Vec3 ToWorldPoint(Vec3 p) const { return m ? TransformPoint(m, p) : p; }
    Vec3 ToLightDir(Vec3 d) const { return m ? Normalize(TransformByInverse(n, d)) : d; }
    Vec3 ToLightPoint(Vec3 p) const { return m ? TransformByInverse(n, p - Vec3(m[3], m[7], m[11])) : p; }
};

}  // namespace

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
    if (kFullFeatures && e.kind == LightKind::kSphere) return spheres_[e.index].radiance;
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
    LightFrame f;
    f.m = EmitterMotionAt(e, f.m_scratch, f.n);
    switch (e.kind) {
        case LightKind::kPoint:
            if (!points_[e.index].Sample(f.ToLightPoint(ref), out)) return false;
            if (f.m) {  // sampled as the light stands in its description: back to where it is now
                out->p = f.ToWorldPoint(out->p);
                out->wi = f.ToWorldDir(out->wi);
            }
            return true;
        case LightKind::kDistant:
            if (!distants_[e.index].Sample(u, e.one_minus_cos, out)) return false;
            out->wi = f.ToWorldDir(out->wi);
            return true;
        case LightKind::kDome:
            if (!dome_.SampleLight(u, out)) return false;
            out->wi = f.ToWorldDir(out->wi);
            return true;
        case LightKind::kSphere: return SphereAt(e.index).Sample(ref, u, out);
        case LightKind::kTriangle: {
            if (!TriangleLightOf(e).Sample(
                    ref, u, [&](float b1, float b2) { return TriangleEmission(e.mesh, e.index, b1, b2); }, out))
                return false;
            const Material& m = MaterialOf(e.mesh, e.index);
            if (m.emission_shaping >= 0)  // toward ref, about the side it faces
                out->radiance = out->radiance * EmissionShaping(m, Dot(out->n, out->wi) <= 0.f ? out->n : -out->n,
                                                                -out->wi);
            return true;
        }
    }
    return false;
}

bool Scene::SampleEmission(uint32_t emitter, Vec2 u_pos, Vec2 u_dir, float u_side, EmissionSample* out) const {
    const Emitter& e = emitters_[emitter];
    out->on_surface = false;
    switch (e.kind) {
        case LightKind::kTriangle: {
            if (!TriangleLightOf(e).SampleEmission(
                    u_pos, u_dir, u_side,
                    [&](float b1, float b2) { return TriangleEmission(e.mesh, e.index, b1, b2); }, out))
                return false;
            out->Le_unshaped = out->Le;
            const Material& m = MaterialOf(e.mesh, e.index);
            if (m.emission_shaping >= 0) {  // out->n is the side it leaves from
                const Color f = EmissionShaping(m, out->n, out->wo);
                out->beta = out->beta * f;
                out->Le = out->Le * f;
            }
            return true;
        }
        case LightKind::kSphere:
            if (!SphereAt(e.index).SampleEmission(u_pos, u_dir, e.area, out)) return false;
            out->Le_unshaped = out->Le;
            return true;
        case LightKind::kPoint: {
            if (!points_[e.index].SampleEmission(u_dir, out)) return false;
            LightFrame f;
            if ((f.m = EmitterMotionAt(e, f.m_scratch, f.n))) {
                out->p = f.ToWorldPoint(out->p);
                out->wo = f.ToWorldDir(out->wo);
            }
            return true;
        }
        case LightKind::kDistant:
        case LightKind::kDome: {
            float pdf_dir = 1.f;
            Color L;
            Vec3 wo;
            if (e.kind == LightKind::kDome) {
                wo = -dome_.Sample(u_dir, &pdf_dir, &L);  // light travels away from the dome
                if (!(pdf_dir > 0.f)) return false;
            } else {
                distants_[e.index].SampleEmissionDirection(u_dir, e.one_minus_cos, &wo, &pdf_dir, &L);
            }
            LightFrame f;
            f.m = EmitterMotionAt(e, f.m_scratch, f.n);
            wo = f.ToWorldDir(wo);
            SampleInfiniteEmission(wo, pdf_dir, L, u_pos, scene_center_, scene_radius_, out);
            out->delta_light = e.kind == LightKind::kDistant && e.one_minus_cos == 0.f;
            return true;
        }
    }
    return false;
}

float Scene::EmissionPdfDirection(uint32_t emitter, Vec3 n, Vec3 w) const {
    const Emitter& e = emitters_[emitter];
    switch (e.kind) {
        case LightKind::kPoint: return PointLight::PdfDirection();
        case LightKind::kSphere: return SphereLight::PdfDirection(n, w);
        case LightKind::kTriangle:
            return TriangleLightPdfDirection(MaterialOf(e.mesh, e.index).two_sided_emission, n, w);
        case LightKind::kDistant: return DistantLight::PdfDirection(e.one_minus_cos);
        case LightKind::kDome: {
            LightFrame f;
            f.m = EmitterMotionAt(e, f.m_scratch, f.n);
            return dome_.PdfDirection(f.ToLightDir(w));
        }
    }
    return 0.f;
}

bool Scene::EmissionToward(uint32_t emitter, const EmissionSample& es, Vec3 w, Color* Le_cos, float* pdf_dir) const {
    const Emitter& e = emitters_[emitter];
    *Le_cos = Color(0.f);
    *pdf_dir = 0.f;
    switch (e.kind) {
        case LightKind::kSphere: {
            const float c = Dot(es.n, w);
            *pdf_dir = SphereLight::PdfDirection(es.n, w);
            if (c > 0.f) *Le_cos = es.Le_unshaped * c;
            return true;
        }
        case LightKind::kTriangle: {
            const Material& m = MaterialOf(e.mesh, e.index);
            *pdf_dir = TriangleLightPdfDirection(m.two_sided_emission, es.n, w);
            const float c = Dot(es.n, w);
            if (!(c > 0.f) && !(m.two_sided_emission && c < 0.f)) return true;
            const Vec3 side = c > 0.f ? es.n : -es.n;
            const Color Le = m.emission_shaping < 0 ? es.Le_unshaped : es.Le_unshaped * EmissionShaping(m, side, w);
            *Le_cos = Le * std::abs(c);
            return true;
        }
        case LightKind::kPoint: {
            LightFrame f;
            f.m = EmitterMotionAt(e, f.m_scratch, f.n);
            *pdf_dir = PointLight::PdfDirection();
            *Le_cos = points_[e.index].intensity * points_[e.index].shaping.Factor(f.ToLightDir(w));
            return true;
        }
        case LightKind::kDistant:
        case LightKind::kDome: return false;
    }
    return false;
}

float Scene::EmissionPdfPosition(uint32_t emitter) const {
    const Emitter& e = emitters_[emitter];
    switch (e.kind) {
        case LightKind::kPoint: return PointLight::PdfPosition();
        case LightKind::kSphere:
        case LightKind::kTriangle: return 1.f / EmitterArea(e);
        case LightKind::kDistant:
        case LightKind::kDome: return InfiniteEmissionPdfPosition(scene_radius_);
    }
    return 0.f;
}

float Scene::InfiniteLightDensity(Vec3 w) const {
    float pdf = 0.f;
    for (uint32_t i : environment_lights_) {
        float p = 0.f;
        EnvironmentRadiance(emitters_[i], w, &p);
        pdf += light_sampler_.Pmf(i) * p;
    }
    return pdf;
}

bool Scene::IsInfiniteLight(uint32_t emitter) const {
    LightKind k = emitters_[emitter].kind;
    return k == LightKind::kDistant || k == LightKind::kDome;
}

bool Scene::IsDeltaLight(uint32_t emitter) const {
    const Emitter& e = emitters_[emitter];
    return e.kind == LightKind::kPoint || (e.kind == LightKind::kDistant && e.one_minus_cos == 0.f);
}

Color Scene::EnvironmentRadiance(const Emitter& e, Vec3 dir, float* pdf) const {
    LightFrame f;
    f.m = EmitterMotionAt(e, f.m_scratch, f.n);
    if (e.kind == LightKind::kDome) return dome_.Radiance(f.ToLightDir(dir), pdf);
    return distants_[e.index].Radiance(f.ToLightDir(dir), e.one_minus_cos, pdf);
}

float Scene::EmitterPdf(uint32_t emitter, Vec3 ref, const SurfaceHit& hit) const {
    const Emitter& e = emitters_[emitter];
    if (kFullFeatures && e.kind == LightKind::kSphere) return SphereAt(e.index).Pdf(ref);
    return TriangleLightPdf(ref, hit.p, hit.ng, EmitterArea(e));
}

float Scene::EmitterArea(const Emitter& e) const {
    const bool reshaped = kFullFeatures && has_motion() && e.kind == LightKind::kTriangle &&
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
        return e.kind == LightKind::kTriangle && meshes_[e.mesh].time_steps <= 1 &&
               (e.instance == kNoInstance || instances_[e.instance].time_steps <= 1);
    };
    std::vector<LightBounds> bounds;
    std::vector<uint32_t> ids;
    double bvh_power = 0.0, total = 0.0;
    for (uint32_t i = 0; i < emitters_.size(); ++i) {
        total += power[i];
        if (!still(emitters_[i]) || !(power[i] > 0.0)) continue;
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

bool Scene::SampleLight(float u, Vec3 p, Vec3 n, uint32_t* light, float* pmf) const {
    if (light_bvh_.empty()) {
        *light = light_sampler_.Sample(u, pmf);
        return true;
    }
    const float share = light_bvh_share_;
    if (u < share) {
        const float ub = std::min(u / share, 0x1.fffffep-1f);
        if (!light_bvh_.Sample(ub, p, n, light, pmf)) return false;
        *pmf *= share;
        return true;
    }
    const float uo = std::min((u - share) / (1.f - share), 0x1.fffffep-1f);
    float other = 0.f;
    *light = other_light_ids_[other_lights_.Sample(uo, &other)];
    *pmf = other * (1.f - share);
    return true;
}

float Scene::LightPmf(Vec3 p, Vec3 n, uint32_t light) const {
    if (light_bvh_.empty()) return light_sampler_.Pmf(light);
    if (light >= other_light_index_.size()) return 0.f;
    const int32_t o = other_light_index_[light];
    if (o < 0) return light_bvh_share_ * light_bvh_.Pmf(p, n, light);
    return (1.f - light_bvh_share_) * other_lights_.Pmf(uint32_t(o));
}

}  // namespace tessera
