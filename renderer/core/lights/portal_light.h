// A portal (UsdLux PortalLight): a rectangle, typically a window, through which the dome's
// light enters an interior. Sampling the whole sphere of dome directions wastes most
// samples on walls; a portal instead samples directions through its opening, as pbrt-v4's
// portal infinite light does, and looks the radiance up in the dome in that direction.
//
// What a scene with portals sees (docs/scene-translation.md): the dome lights the scene
// only through its portals. A ray that escapes through a portal sees the dome's radiance
// in its direction; a ray that escapes anywhere else sees black, and the dome adds no
// emitter of its own (EmitterOf<PortalLight>::Guides). This is pbrt-v4's rule and what
// RenderMan's portal lights do; it keeps next event estimation and escaping rays in
// agreement (MIS needs both to describe the same light). Portals must not overlap as seen
// from the scene: a ray through two of them would count the dome twice.
//
// Light subpaths (light, bdpt, vcm, sppm, photon) would start on the portal with a
// direction into the scene; not done: those integrators refuse a scene with portals
// (kStartsLightPaths below, Integrator::Create).
#pragma once

#include <cmath>
#include <limits>
#include <stdexcept>

#include "distant_light.h"
#include "dome_light.h"
#include "light.h"

namespace tessera {

// The rectangle (a parallelogram under shear): centre c and half-edge vectors hu, hv in
// world space; its outward normal Normalize(Cross(hu, hv)) points toward the dome, away
// from the interior it lights (UsdLux: the portal's light travels along its -Z).
struct PortalLight {
    Vec3 center, half_u, half_v;
    Vec3 outward;     // unit, toward the dome
    float area = 0.f;

    // Throws std::invalid_argument for a rectangle without area or with non-finite values.
    PortalLight(Vec3 c, Vec3 hu, Vec3 hv) : center(c), half_u(hu), half_v(hv) {
        const Vec3 n = Cross(hu, hv);
        const float len = Length(n);
        if (!IsFinite(c) || !IsFinite(hu) || !IsFinite(hv) || !(len > 0.f) || !std::isfinite(len))
            throw std::invalid_argument("portal light needs a finite centre and two edges spanning an area");
        outward = n / len;
        area = 4.f * len;
    }

    // The point of the portal's plane at local coordinates (a, b) in [-1, 1]^2.
    Vec3 At(float a, float b) const { return center + half_u * a + half_v * b; }

    // Whether a ray from `origin` along unit `dir` leaves the interior through the opening;
    // its distance to the portal's plane in *t and the cosine with the outward normal in *cos.
    bool Through(Vec3 origin, Vec3 dir, float* t, float* cos) const {
        *cos = Dot(dir, outward);
        const float height = Dot(center - origin, outward);  // > 0: origin on the interior side
        if (!(*cos > 0.f) || !(height > 0.f)) return false;
        *t = height / *cos;
        const Vec3 q = origin + dir * *t - center;
        const Vec3 n = Cross(half_u, half_v);
        const float n2 = Dot(n, n);
        const float a = Dot(Cross(q, half_v), n) / n2, b = Dot(Cross(half_u, q), n) / n2;
        return std::abs(a) <= 1.f && std::abs(b) <= 1.f;
    }

    // A direction from `ref` through the opening, uniform by the portal's area, and its
    // solid-angle density t^2 / (area cos). False when ref is not on the interior side.
    bool SampleDirection(Vec3 ref, Vec2 u, Vec3* wi, float* pdf) const {
        const Vec3 d = At(2.f * u.x - 1.f, 2.f * u.y - 1.f) - ref;
        const float d2 = Dot(d, d);
        if (!(d2 > 0.f)) return false;
        *wi = d / std::sqrt(d2);
        const float cos = Dot(*wi, outward);
        if (!(cos > 0.f) || !(Dot(center - ref, outward) > 0.f)) return false;
        *pdf = d2 / (area * cos);
        return std::isfinite(*pdf);
    }
};

template <>
struct EmitterOf<PortalLight> : InfiniteEmitterAnswers {
    static constexpr const char* kName = "portal";
    static constexpr bool kMoves = false;
    // Portals carry the dome's light: with any portal in the scene the dome adds no
    // emitter of its own (Scene::BuildGeometryAndLights).
    using Guides = DomeLight;
    static constexpr bool kStartsLightPaths = false;
    // The row the binding hands over (SceneDesc::light_rows): centre xyz, half-edge u xyz,
    // half-edge v xyz, world space; the first three columns are a position, as for every
    // kind handed over in rows (the Python side moves them with the camera).
    static constexpr size_t kRowColumns = 9;
    static PortalLight FromRow(const float* r) {
        return PortalLight(Vec3(r[0], r[1], r[2]), Vec3(r[3], r[4], r[5]), Vec3(r[6], r[7], r[8]));
    }

    template <class S>
    static const DomeLight& DomeOf(const S& s) {
        return s.lights_.template Of<DomeLight>()[0];
    }
    template <class S, class E>
    static bool Sample(const S& s, const E& e, Vec3 ref, Vec2 u, LightSample* out) {
        const PortalLight& portal = s.lights_.template Of<PortalLight>()[e.index];
        if (!portal.SampleDirection(ref, u, &out->wi, &out->pdf)) return false;
        float unused;
        out->radiance = DomeOf(s).Radiance(out->wi, &unused);
        out->distance = std::numeric_limits<float>::infinity();
        out->n = Vec3(0.f);
        return true;
    }
    template <class S, class E>
    static bool SampleEmission(const S&, const E&, Vec2, Vec2, float, EmissionSample*) {
        return false;  // refused before rendering (kStartsLightPaths)
    }
    template <class S, class E>
    static float PdfDirection(const S&, const E&, Vec3, Vec3) {
        return 0.f;
    }
    template <class E>
    static bool Delta(const E&) {
        return false;
    }
    template <class S, class E>
    static Color Environment(const S& s, const E& e, Vec3 origin, Vec3 dir, float* pdf) {
        const PortalLight& portal = s.lights_.template Of<PortalLight>()[e.index];
        float t, cos;
        if (!portal.Through(origin, dir, &t, &cos)) {
            *pdf = 0.f;
            return Color(0.f);
        }
        *pdf = t * t / (portal.area * cos);
        float unused;
        return DomeOf(s).Radiance(dir, &unused);
    }
    // Power for choosing among lights: a uniform dome of radiance L sends pi L A through
    // an opening of area A (the texture's mean stands in for L).
    template <class S, class Add>
    static void AddEmitters(const S& s, Add&& add) {
        const DomeLight& dome = DomeOf(s);
        if (!dome.active()) return;
        const double L = double(Luminance(dome.radiance())) * dome.MeanLuminance();
        const auto& portals = s.lights_.template Of<PortalLight>();
        for (uint32_t i = 0; i < portals.size(); ++i) add(i, portals[i].area, 0.f, kPi * portals[i].area * L, true);
    }
};

}  // namespace tessera
