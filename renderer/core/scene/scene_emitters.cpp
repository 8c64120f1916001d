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

int32_t Scene::EmitterAt(const SurfaceHit& hit) const {
    if (hit.geom_id != kTriangleGeometry) return sphere_emitter_[hit.prim_id];
    const int32_t local = meshes_[hit.mesh].emitter[hit.prim_id];
    if (hit.instance == kNoInstance || local < 0) return local;
    return instances_[hit.instance].emitter_base + local;
}

Color Scene::Emitted(int32_t emitter, const SurfaceHit& hit, Vec3 wo) const {
    if (emitter < 0) return Color(0.f);
    const Emitter& e = emitters_[emitter];
    if (e.kind == LightKind::kSphere) return spheres_[e.index].radiance;
    const Material& m = MaterialOf(e.mesh, e.index);
    if (!m.two_sided_emission && !(Dot(hit.ng, wo) > 0.f)) return Color(0.f);
    return TriangleEmission(e.mesh, e.index, hit.b1, hit.b2);
}

TriangleLight Scene::TriangleLightOf(const Emitter& e) const {
    TriangleLight t;
    Vec3 tri[3];
    t.orientation = TriangleVertices(e.mesh, e.index, e.instance, tri);
    t.p0 = tri[0];
    t.p1 = tri[1];
    t.p2 = tri[2];
    t.area = EmitterArea(e);
    t.two_sided = MaterialOf(e.mesh, e.index).two_sided_emission;
    t.instanced = e.instance != kNoInstance;
    return t;
}

bool Scene::SampleEmitter(uint32_t emitter, Vec3 ref, Vec2 u, LightSample* out) const {
    const Emitter& e = emitters_[emitter];
    out->is_delta = false;
    switch (e.kind) {
        case LightKind::kPoint: return points_[e.index].Sample(ref, out);
        case LightKind::kDistant: return distants_[e.index].Sample(u, e.one_minus_cos, out);
        case LightKind::kDome: return dome_.SampleLight(u, out);
        case LightKind::kSphere: return spheres_[e.index].Sample(ref, u, out);
        case LightKind::kTriangle:
            return TriangleLightOf(e).Sample(
                ref, u, [&](float b1, float b2) { return TriangleEmission(e.mesh, e.index, b1, b2); }, out);
    }
    return false;
}

bool Scene::SampleEmission(uint32_t emitter, Vec2 u_pos, Vec2 u_dir, float u_side, EmissionSample* out) const {
    const Emitter& e = emitters_[emitter];
    out->on_surface = false;
    switch (e.kind) {
        case LightKind::kTriangle:
            return TriangleLightOf(e).SampleEmission(
                u_pos, u_dir, u_side, [&](float b1, float b2) { return TriangleEmission(e.mesh, e.index, b1, b2); },
                out);
        case LightKind::kSphere: return spheres_[e.index].SampleEmission(u_pos, u_dir, e.area, out);
        case LightKind::kPoint: return points_[e.index].SampleEmission(u_dir, out);
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
        case LightKind::kDome: return dome_.PdfDirection(w);
    }
    return 0.f;
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
    if (e.kind == LightKind::kDome) return dome_.Radiance(dir, pdf);
    return distants_[e.index].Radiance(dir, e.one_minus_cos, pdf);
}

float Scene::EmitterPdf(uint32_t emitter, Vec3 ref, const SurfaceHit& hit) const {
    const Emitter& e = emitters_[emitter];
    if (e.kind == LightKind::kSphere) return spheres_[e.index].Pdf(ref);
    return TriangleLightPdf(ref, hit.p, hit.ng, EmitterArea(e));
}

float Scene::EmitterArea(const Emitter& e) const {
    const bool reshaped = e.kind == LightKind::kTriangle &&
                          (meshes_[e.mesh].time_steps > 1 ||
                           (e.instance != kNoInstance && instances_[e.instance].time_steps > 1));
    if (!reshaped) return e.area;
    // A moving instance may scale its triangles, a deforming mesh reshape them: the area now.
    Vec3 p[3];
    TriangleVertices(e.mesh, e.index, e.instance, p);
    return std::max(1e-30f, 0.5f * Length(Cross(p[1] - p[0], p[2] - p[0])));
}

}  // namespace tessera
