// BDPT's internals (subpath vertices, densities, connections, MIS weights), shared by
// bdpt.cpp and the unit tests that check them (renderer/core/integrators/bdpt_mis_test.cpp). Everything
// here is inline, as it was when it lived in bdpt.cpp: the hot path is unchanged.
#pragma once

#include <algorithm>
#include <limits>

#include "bsdf.h"
#include "camera.h"
#include "light_tracer.h"
#include "sampler.h"
#include "sampling.h"
#include "scene.h"

namespace tessera::bdpt_internal {

enum class VertexType : uint8_t { kCamera, kLight, kSurface };

// A subpath vertex. Densities are per unit area at the vertex, except at a light at
// infinity, where they are per unit solid angle of its direction.
struct Vertex {
    VertexType type = VertexType::kSurface;
    bool delta = false;        // scattered by a delta lobe: cannot be connected to
    bool infinite = false;     // a light at infinity: only its direction matters
    bool delta_light = false;  // a point or delta-distant light: cannot be hit
    bool parallel = false;     // an orthographic camera: densities from it are per film area
    int32_t emitter = -1;      // light vertices; surface vertices that emit
    bool importance = false;   // on a light subpath: BSDFs transport importance
    Vec3 p, ng;                // ng is zero off surfaces (pinhole, points, infinity)
    float p_error = 0.f;       // surfaces: SurfaceHit::p_error (OffsetRayOrigin)
    Vec3 ns;                   // shading normal (surfaces; = ng on lights)
    Vec3 wo;                   // surfaces: toward the previous vertex of the subpath
    Vec3 dir;                  // lights at infinity: the direction the light travels
    Color beta;                // subpath throughput up to and including this vertex
    float pdf_fwd = 0.f, pdf_rev = 0.f;
    BSDF bsdf;
    Frame frame;
    SurfaceHit hit;

    bool OnSurface() const { return ng.x != 0.f || ng.y != 0.f || ng.z != 0.f; }
    bool IsLight() const { return type == VertexType::kLight || (type == VertexType::kSurface && emitter >= 0); }
    bool Connectible() const {
        switch (type) {
            case VertexType::kCamera: return true;
            case VertexType::kLight: return !infinite;  // its position is not a real one
            case VertexType::kSurface: return bsdf.IsNonSpecular();
        }
        return false;
    }
};

inline float Remap0(float f) { return f != 0.f ? f : 1.f; }

// Vertex merging (vcm) can end a light and a camera subpath at this vertex: a surface
// scattered by a non-delta lobe on the path.
inline bool Mergeable(const Vertex& v) {
    return v.type == VertexType::kSurface && !v.delta && v.bsdf.IsNonSpecular();
}

// Unit direction from `from` toward `to`.
inline Vec3 DirectionTo(const Vertex& from, const Vertex& to) {
    if (to.infinite) return -to.dir;
    return Normalize(to.p - from.p);
}

// Solid-angle density at `from` converted to the measure of `to`.
// From an orthographic camera the density is per unit film area, and a parallel beam
// keeps it along the ray: only `to`'s cosine converts it.
inline float ConvertDensity(float pdf, const Vertex& from, const Vertex& to) {
    if (to.infinite) return pdf;
    Vec3 w = to.p - from.p;
    float d2 = LengthSquared(w);
    if (!(d2 > 0.f)) return 0.f;
    if (from.parallel) return to.OnSurface() ? pdf * std::abs(Dot(to.ng, w)) / std::sqrt(d2) : pdf;
    if (to.OnSurface()) pdf *= std::abs(Dot(to.ng, w)) / std::sqrt(d2);
    return pdf / d2;
}

class Walker {
public:
    Walker(const Scene& scene, const Camera& camera, int max_depth)
        : scene_(scene), camera_(camera), max_depth_(max_depth) {}

    // BSDF value at surface vertex v for light going between `v.wo` and `next`.
    Color F(const Vertex& v, const Vertex& next) const {
        Vec3 wi = DirectionTo(v, next);
        Vec3 wo_local = v.frame.ToLocal(v.wo), wi_local = v.frame.ToLocal(wi);
        if (!SidesAgree(v.wo, wi, v.ng, wo_local, wi_local)) return Color(0.f);
        Color f = v.bsdf.f(wo_local, wi_local);
        return v.importance ? f * ImportanceShadingCorrection(v.wo, wi, v.ns, v.ng) : f;
    }

    // Density, in the measure of `next`, that `v` (reached from `prev`) samples `next`.
    float Pdf(const Vertex& v, const Vertex* prev, const Vertex& next) const {
        if (v.type == VertexType::kLight) return PdfLight(v, next);
        Vec3 wn = DirectionTo(v, next);
        float pdf;
        if (v.type == VertexType::kCamera) {
            pdf = camera_.PdfDirection(v.p, wn);
        } else {
            Vec3 wp = DirectionTo(v, *prev);
            pdf = v.bsdf.PDF(v.frame.ToLocal(wp), v.frame.ToLocal(wn));
        }
        return ConvertDensity(pdf, v, next);
    }

    // Density at `next` of light vertex (or emitting surface) `v` emitting toward it.
    float PdfLight(const Vertex& v, const Vertex& next) const {
        if (v.infinite) {
            // A parallel beam through the bounding disk.
            float pdf = 1.f / (kPi * scene_.scene_radius() * scene_.scene_radius());
            if (next.OnSurface()) pdf *= std::abs(Dot(next.ng, v.dir));
            return pdf;
        }
        Vec3 w = next.p - v.p;
        float d2 = LengthSquared(w);
        if (!(d2 > 0.f)) return 0.f;
        w = w / std::sqrt(d2);
        float pdf = scene_.EmissionPdfDirection(uint32_t(v.emitter), v.ng, w) / d2;
        if (next.OnSurface()) pdf *= std::abs(Dot(next.ng, w));
        return pdf;
    }

    // Density of light vertex `v` being chosen as a light subpath's origin (`next` is the
    // vertex it lights, which fixes the direction for lights at infinity).
    float PdfLightOrigin(const Vertex& v, const Vertex& next) const {
        if (v.infinite) return scene_.InfiniteLightDensity(next.p, DirectionTo(next, v));
        if (v.emitter < 0) return 0.f;
        return scene_.light_sampler().Pmf(uint32_t(v.emitter)) * scene_.EmissionPdfPosition(uint32_t(v.emitter));
    }

    // Radiance that light vertex / emitting surface `v` sends toward `to`.
    Color Le(const Vertex& v, const Vertex& to) const {
        if (v.infinite) {
            Color L(0.f);
            scene_.ForEachEnvironmentLight(to.p, -v.dir, [&](uint32_t, Color Le, float) { L += Le; });
            return L;
        }
        if (v.emitter < 0) return Color(0.f);
        return scene_.Emitted(v.emitter, v.hit, Normalize(to.p - v.p));
    }

    // Extends path[0..] (path[-1] is the previous vertex) by up to `max_vertices`.
    // t_min / t_max clip the first segment only (the camera's clipping range).
    int RandomWalk(Ray ray, Color beta, float pdf, int max_vertices, TransportMode mode, PixelSampler& sampler,
                   Vertex* path, float t_min = 0.f, float t_max = std::numeric_limits<float>::infinity()) const {
        if (max_vertices == 0) return 0;
        int n = 0;
        float pdf_fwd = pdf;
        float eta_scale = 1.f;
        const float roulette_scale = RouletteScale(beta);
        while (true) {
            Vertex& prev = path[n - 1];
            Vertex& v = path[n];
            SurfaceHit hit;
            const bool first = n == 0;
            if (!scene_.Intersect(ray, &hit, first ? t_min : 0.f,
                                  first ? t_max : std::numeric_limits<float>::infinity())) {
                // A camera ray escaping to lights at infinity ends the subpath on one of them.
                if (mode == TransportMode::Radiance && scene_.has_environment()) {
                    v = Vertex{};
                    v.type = VertexType::kLight;
                    v.infinite = true;
                    v.dir = -ray.d;
                    v.p = ray.o + ray.d * (2.f * scene_.scene_radius());
                    v.beta = beta;
                    v.pdf_fwd = pdf_fwd;
                    ++n;
                }
                break;
            }
            v = Vertex{};
            v.type = VertexType::kSurface;
            v.p = hit.p;
            v.p_error = hit.p_error;
            v.ng = hit.ng;
            v.ns = hit.ns;
            v.importance = mode == TransportMode::Importance;
            v.wo = -ray.d;
            v.hit = hit;
            v.emitter = scene_.EmitterAt(hit);
            v.bsdf = scene_.BSDFAt(hit, mode);
            v.frame = Frame::FromZ(hit.ns);
            v.beta = beta;
            v.pdf_fwd = ConvertDensity(pdf_fwd, prev, v);
            if (++n >= max_vertices) break;
            if (v.bsdf.Flags() == kBSDFUnset) break;

            const Vec3 wo_local = v.frame.ToLocal(v.wo);
            const float uc = sampler.Get1D();
            const std::optional<BSDFSample> bs = v.bsdf.Sample_f(wo_local, uc, sampler.Get2D());
            if (!bs || !(bs->pdf > 0.f) || IsBlack(bs->f)) break;
            pdf_fwd = bs->pdf;
            float pdf_rev = v.bsdf.PDF(bs->wi, wo_local);
            if (bs->is_specular) {
                v.delta = true;
                pdf_fwd = pdf_rev = 0.f;
            }
            const Vec3 wi = Normalize(v.frame.FromLocal(bs->wi));
            if (!SidesAgree(v.wo, wi, v.ng, wo_local, bs->wi)) break;
            beta *= bs->f * (std::abs(bs->wi.z) / bs->pdf);
            if (v.importance) beta *= ImportanceShadingCorrection(v.wo, wi, v.ns, v.ng);
            if (bs->is_transmission) eta_scale *= bs->eta * bs->eta;
            prev.pdf_rev = ConvertDensity(pdf_rev, v, prev);
            ray = {OffsetRayOrigin(hit.p, hit.p_error, hit.ng, wi), wi};
            // Russian roulette past the third vertex (throughput only: see the header), on
            // the throughput relative to the subpath's start.
            if (n >= 3) {
                float q = std::min(1.f, MaxComponent(beta) * eta_scale * roulette_scale);
                if (sampler.Get1D() >= q) break;
                beta = beta / q;
            }
        }
        return n;
    }

    int CameraSubpath(const Ray& ray, PixelSampler& sampler, Vertex* path) const {
        path[0] = Vertex{};
        path[0].type = VertexType::kCamera;
        path[0].p = ray.o;  // the lens point (orthographic: the film point)
        path[0].parallel = camera_.IsOrthographic();
        path[0].beta = Color(1.f);
        float t_min, t_max;
        camera_.ClipRange(ray.d, &t_min, &t_max);
        return 1 + RandomWalk(ray, Color(1.f), camera_.PdfDirection(ray.o, ray.d), max_depth_ + 1,
                              TransportMode::Radiance, sampler, path + 1, t_min, t_max);
    }

    int LightSubpath(PixelSampler& sampler, Vertex* path) const {
        const LightSampler& lights = scene_.light_sampler();
        if (lights.empty()) return 0;
        float pmf = 0.f;
        uint32_t light = lights.Sample(sampler.Get1D(), &pmf);
        Vec2 u_pos = sampler.Get2D(), u_dir = sampler.Get2D();
        float u_side = sampler.Get1D();
        EmissionSample es;
        if (!scene_.SampleEmission(light, u_pos, u_dir, u_side, &es) || !(pmf > 0.f) || !(es.pdf_pos > 0.f) ||
            !(es.pdf_dir > 0.f))
            return 0;
        Vertex& v = path[0];
        v = Vertex{};
        v.type = VertexType::kLight;
        v.emitter = int32_t(light);
        v.p = es.p;
        v.p_error = es.p_error;
        v.ng = es.on_surface ? es.n : Vec3(0.f);
        v.ns = v.ng;
        v.infinite = es.infinite;
        v.delta_light = es.delta_light;
        v.dir = es.wo;
        v.beta = es.Le / (pmf * es.pdf_pos);
        v.pdf_fwd = pmf * es.pdf_pos;
        Ray ray{es.on_surface ? OffsetRayOrigin(es.p, es.p_error, es.n, es.wo) : es.p, es.wo};
        int n = 1 + RandomWalk(ray, es.beta / pmf, es.pdf_dir, max_depth_, TransportMode::Importance, sampler, path + 1);
        if (es.infinite) {
            // From infinity: the first hit's density is the disk's, projected; the origin's
            // is the density of its direction.
            if (n > 1) {
                path[1].pdf_fwd = es.pdf_pos;
                if (path[1].OnSurface()) path[1].pdf_fwd *= std::abs(Dot(es.wo, path[1].ng));
            }
            v.pdf_fwd = scene_.InfiniteLightDensity(n > 1 ? path[1].p : es.p, -es.wo);
        }
        return n;
    }

    // The power-heuristic weight of strategy (s, t) for the path it built; `sampled`
    // stands in for light[0] (s = 1) or camera[0] (t = 1) as the strategy's own endpoint.
    // It is read in place, not copied into the subpath (a vertex is 400 bytes and this
    // runs for every strategy); its densities are changed and restored on return.
    // `merge_eta` > 0 (vcm: light paths merged per camera sample times the merging disk's
    // area) also counts vertex merging at every interior non-delta surface vertex y_j with
    // j >= `first_merge` (y_0 the light's vertex), whose density relative to the
    // connection with that vertex first on the camera side is its light-side density
    // times merge_eta (Georgiev et al. 2012); 0 is plain BDPT.
    float MISWeight(Vertex* light, Vertex* camera, Vertex& sampled, int s, int t, float merge_eta = 0.f,
                    int first_merge = 1) const {
        if (s + t == 2) return 1.f;
        // Vertex i of each subpath as this strategy sees it.
        auto light_at = [&](int i) -> Vertex& { return s == 1 && i == 0 ? sampled : light[i]; };
        auto camera_at = [&](int i) -> Vertex& { return t == 1 && i == 0 ? sampled : camera[i]; };
        Vertex* qs = s > 0 ? &light_at(s - 1) : nullptr;
        Vertex* pt = &camera_at(t - 1);
        Vertex* qs_minus = s > 1 ? &light_at(s - 2) : nullptr;
        Vertex* pt_minus = t > 1 ? &camera_at(t - 2) : nullptr;
        // Saved values restored below: the connection endpoints are not delta, and their
        // reverse densities are those of the hypothetical strategies through this edge.
        const bool pt_delta = pt->delta, qs_delta = qs ? qs->delta : false;
        const float pt_rev = pt->pdf_rev, pt_minus_rev = pt_minus ? pt_minus->pdf_rev : 0.f;
        const float qs_rev = qs ? qs->pdf_rev : 0.f, qs_minus_rev = qs_minus ? qs_minus->pdf_rev : 0.f;
        pt->delta = false;
        if (qs) qs->delta = false;
        pt->pdf_rev = s > 0 ? Pdf(*qs, qs_minus, *pt) : PdfLightOrigin(*pt, *pt_minus);
        if (pt_minus) pt_minus->pdf_rev = s > 0 ? Pdf(*pt, qs, *pt_minus) : PdfLight(*pt, *pt_minus);
        if (qs) qs->pdf_rev = Pdf(*pt, pt_minus, *qs);
        if (qs_minus) qs_minus->pdf_rev = Pdf(*qs, pt, *qs_minus);

        // Ratios p_i / p_s of the other strategies along each subpath.
        float sum = 0.f, r = 1.f;
        for (int i = t - 1; i > 0; --i) {
            const Vertex& ci = camera_at(i);
            // Merging at camera[i], which is y_{s + t - 1 - i} (never the light's own vertex,
            // which s = 0 puts last).
            if (merge_eta > 0.f && Mergeable(ci) && s + t - 1 - i >= std::max(first_merge, 1)) {
                const float m = r * Remap0(ci.pdf_rev) * merge_eta;
                sum += m * m;
            }
            r *= Remap0(ci.pdf_rev) / Remap0(ci.pdf_fwd);
            if (!ci.delta && !camera_at(i - 1).delta) sum += r * r;
        }
        r = 1.f;
        for (int i = s - 1; i >= 0; --i) {
            const Vertex& li = light_at(i);
            r *= Remap0(li.pdf_rev) / Remap0(li.pdf_fwd);
            bool delta_before = i > 0 ? light_at(i - 1).delta : li.delta_light;
            if (!li.delta && !delta_before) sum += r * r;
            if (merge_eta > 0.f && i >= std::max(first_merge, 1) && Mergeable(li)) {
                const float m = r * Remap0(li.pdf_fwd) * merge_eta;
                sum += m * m;
            }
        }

        pt->delta = pt_delta;
        pt->pdf_rev = pt_rev;
        if (pt_minus) pt_minus->pdf_rev = pt_minus_rev;
        if (qs) {
            qs->delta = qs_delta;
            qs->pdf_rev = qs_rev;
        }
        if (qs_minus) qs_minus->pdf_rev = qs_minus_rev;
        return 1.f / (1.f + sum);
    }

    // Unweighted contribution of strategy (s, t). For t = 1 writes the raster position.
    Color Connect(Vertex* light, Vertex* camera, int s, int t, PixelSampler& sampler, Vertex* sampled, float* px,
                  float* py) const {
        if (t > 1 && s != 0 && camera[t - 1].type == VertexType::kLight) return Color(0.f);
        if (s == 0) {
            const Vertex& pt = camera[t - 1];
            if (!pt.IsLight()) return Color(0.f);
            return pt.beta * Le(pt, camera[t - 2]);
        }
        if (t == 1) {
            const Vertex& qs = light[s - 1];
            if (!qs.Connectible() || qs.type != VertexType::kSurface) return Color(0.f);
            Vec3 wc;
            float importance;
            Vec3 lens;
            if (!ConnectToCamera(scene_, camera_, qs.p, qs.p_error, qs.ng, sampler.Get2D(), px, py, &wc, &importance, &lens))
                return Color(0.f);
            *sampled = Vertex{};
            sampled->type = VertexType::kCamera;
            sampled->p = lens;
            sampled->parallel = camera_.IsOrthographic();
            return qs.beta * F(qs, *sampled) * (std::abs(Dot(wc, qs.ns)) * importance);
        }
        if (s == 1) {
            const Vertex& pt = camera[t - 1];
            if (!pt.Connectible()) return Color(0.f);
            const LightSampler& lights = scene_.light_sampler();
            if (lights.empty()) return Color(0.f);
            float pmf = 0.f;
            uint32_t light_index = lights.Sample(sampler.Get1D(), &pmf);
            LightSample ls;
            if (!scene_.SampleEmitter(light_index, pt.p, sampler.Get2D(), &ls) || !(ls.pdf > 0.f)) return Color(0.f);
            *sampled = Vertex{};
            sampled->type = VertexType::kLight;
            sampled->emitter = int32_t(light_index);
            sampled->infinite = scene_.IsInfiniteLight(light_index);
            sampled->delta_light = scene_.IsDeltaLight(light_index);
            sampled->dir = -ls.wi;
            sampled->p = sampled->infinite ? pt.p + ls.wi * (2.f * scene_.scene_radius()) : pt.p + ls.wi * ls.distance;
            sampled->ng = sampled->ns = ls.n;
            sampled->beta = ls.radiance / (pmf * ls.pdf);
            sampled->pdf_fwd = PdfLightOrigin(*sampled, pt);
            Color f = F(pt, *sampled) * std::abs(Dot(ls.wi, pt.ns));
            if (IsBlack(f) || IsBlack(sampled->beta)) return Color(0.f);
            if (!scene_.Unoccluded(pt.p, pt.p_error, pt.ng, ls))
                return Color(0.f);
            return pt.beta * f * sampled->beta;
        }
        const Vertex& qs = light[s - 1];
        const Vertex& pt = camera[t - 1];
        if (!qs.Connectible() || !pt.Connectible()) return Color(0.f);
        Vec3 d = pt.p - qs.p;
        float d2 = LengthSquared(d);
        if (!(d2 > 0.f)) return Color(0.f);
        // Each end must lie on a side of the other's surface that rounding cannot flip. A hit
        // point near an edge of a closed mesh can be rounded (by up to its p_error) past the
        // neighbouring face's plane; a vertex on that face's other side would then seem to
        // face it, and the unoccluded segment between them would carry light through the
        // edge. Such connections have |cos| ~ 1e-7 and are dropped.
        const float slack = qs.p_error + pt.p_error;
        auto undecided = [&](Vec3 n) {
            return std::abs(Dot(d, n)) <= slack * (std::abs(n.x) + std::abs(n.y) + std::abs(n.z));
        };
        if (undecided(qs.ng) || undecided(pt.ng)) return Color(0.f);
        float dist = std::sqrt(d2);
        Vec3 w = d / dist;  // from qs to pt
        Color L = qs.beta * F(qs, pt) * F(pt, qs) * pt.beta;
        if (IsBlack(L)) return Color(0.f);
        // Cosines at the BSDFs are taken to the shading normals (ng off surfaces is zero,
        // but both ends here are surfaces).
        float g = std::abs(Dot(qs.ns, w)) * std::abs(Dot(pt.ns, w)) / d2;
        if (!(g > 0.f)) return Color(0.f);
        if (!scene_.Unoccluded(qs.p, qs.p_error, qs.ng, pt.p, pt.p_error, pt.ng)) return Color(0.f);
        return L * g;
    }

private:
    const Scene& scene_;
    const Camera& camera_;
    int max_depth_;
};

// The camera subpath of a pixel sample, or for one without camera work (a pixel outside a
// crop, whose only wanted strategies are t = 1) as little of it as keeps those strategies'
// splats: they read no camera vertex, only the lens sample Connect draws from the camera
// stream after the subpath. A pinhole or orthographic camera ignores that sample, so the
// subpath is skipped (1: the camera's own vertex, unread by t = 1); a thin lens needs the
// full render's value, so the subpath is traced to draw it at the same dimension.
inline int CameraSubpathFor(const Walker& walker, const Camera& camera, const Ray& ray, PixelSampler& sampler,
                            Vertex* path, bool camera_work) {
    if (!camera_work && !camera.HasLens()) return 1;
    return walker.CameraSubpath(ray, sampler, path);
}

}  // namespace tessera::bdpt_internal
