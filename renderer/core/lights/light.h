// What every light kind hands the integrators: a sample of the light seen from a point
// (next event estimation) and a sample of light leaving it (light subpaths). Each kind
// lives in its own file (area triangles, spheres, points, distant lights, the dome): the
// light itself, and EmitterOf<Kind>, what the Scene's emitter queries ask of it (Sample,
// SampleEmission, the densities PdfDirection and PdfPosition of SampleEmission, ...).
// The kinds are listed once, in light_kinds.h; Scene dispatches on LightKind (a tag, not
// a virtual call), so the hot loops stay free of indirection and allocation.
#pragma once

#include <cstdint>

#include "math.h"

namespace tessera {

// A kind's position in LightKinds (light_kinds.h): kKindOf<PointLight>, never a literal.
enum class LightKind : uint8_t {};

// A kind as an emitter of the Scene: specialised in the kind's own file, beside the light.
// Its static functions take the scene (S, a friend's view of it) and the emitter record E.
template <typename Kind>
struct EmitterOf;

// What the kinds with a surface in the scene (triangles, spheres) answer alike: a point on
// them is chosen by area, they are neither at infinity nor delta lights, and a ray that
// escapes the scene sees nothing of them. Their EmitterOf derives from it.
struct AreaEmitterAnswers {
    template <class S, class E>
    static float PdfPosition(const S& s, const E& e) {
        return 1.f / s.EmitterArea(e);
    }
    template <class E>
    static bool Infinite(const E&) {
        return false;
    }
    template <class E>
    static bool Delta(const E&) {
        return false;
    }
    template <class S, class E>
    static Color Environment(const S&, const E&, Vec3, Vec3, float*) {
        return Color(0.f);
    }
};

struct LightSample {
    Color radiance;  // arriving at the reference point (for delta lights, already / distance^2)
    Vec3 wi;         // unit direction from the reference point to the light
    float distance = 0.f;  // infinity for lights at infinity
    float pdf = 0.f;       // solid-angle density at the reference point, light already chosen
    bool is_delta = false; // point or delta-distant light: pdf is a probability, no MIS
    Vec3 n;                // the light's surface normal at the sample (zero for points, infinity)
    // The sampled point (finite distance only) and its error bound as SurfaceHit::p_error:
    // the shadow ray stops short of the light's own surface by that bound (Scene::Unoccluded).
    Vec3 p;
    float p_error = 0.f;
};

// The start of a light subpath: a ray leaving a light, and its throughput
// Le |cos| / (pdf_position pdf_direction), not yet divided by the light's selection pmf.
struct EmissionSample {
    Vec3 p;
    float p_error = 0.f;      // as SurfaceHit::p_error (surface samples)
    Vec3 wo;     // unit direction the light travels
    Color beta;
    bool on_surface = false;  // p lies on a surface (offset the ray); not for points and infinite lights
    Vec3 n;                   // that surface's normal on the emitting side
    // The factors of beta, for bidirectional MIS: beta = Le |cos| / (pdf_pos pdf_dir).
    Color Le;                 // radiance (intensity for points, irradiance for delta-distant)
    Color Le_unshaped;        // area lights: Le before the emitter's directional shaping
    float pdf_pos = 0.f;      // area density (1 for points; the bounding disk's for infinity)
    float pdf_dir = 0.f;      // solid-angle density (1 for delta-distant)
    bool infinite = false;    // a light at infinity: p is on the bounding disk, not the light
    bool delta_light = false; // point or delta-distant: no path can hit it
};

}  // namespace tessera
