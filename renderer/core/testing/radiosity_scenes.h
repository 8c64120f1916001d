// Scenes the radiosity solvers' tests share: the closed furnace box (FurnaceBox, below) and
// a room, a 2 x 2 x 2 box of coloured walls lit by a small
// area light under its ceiling, with a grey blocker halfway up that shadows most of the
// floor (lit only in the blocker's penumbra), meshed at element size 0.4 (808 elements).
// Get() is the room of coloured walls (0.7, 0.5, 0.3); other wall albedos build their own.
#pragma once

#include <cmath>
#include <vector>

#include "progressive_solver.h"
#include "radiosity_mesh.h"
#include "scene_helpers.h"

namespace tessera_test {

struct RadiosityRoom {
    tessera::SceneDesc desc;
    tessera::Scene scene;
    tessera::RadiosityMesh mesh;

    static constexpr float kElementSize = 0.4f;
    static const RadiosityRoom& Get() {
        static const RadiosityRoom room(tessera::Color(0.7f, 0.5f, 0.3f));
        return room;
    }
    explicit RadiosityRoom(tessera::Color wall_albedo)
        : desc(Describe(wall_albedo)), scene(desc), mesh(scene, kElementSize) {}
    // Settings of a solve of the room (2 threads).
    static tessera::RadiositySettings Settings(float tolerance) {
        tessera::RadiositySettings s;
        s.element_size = kElementSize;
        s.tolerance = tolerance;
        s.threads = 2;
        return s;
    }

    // Per wall (by facing normal: -x, +x, -y, +y, -z, +z), the area-weighted mean of b's
    // radiosity over a's, minus 1 (the light and the blocker left out).
    std::vector<double> WallErrors(const tessera::RadiositySolution& a, const tessera::RadiositySolution& b) const {
        const auto& el = mesh.elements();
        double sa[6] = {}, sb[6] = {};
        for (size_t e = 0; e < el.size(); ++e) {
            if (el[e].center.y > 0.99f && el[e].center.y < 1.98f && std::abs(el[e].n.y) > 0.9f) continue;  // blocker
            if (el[e].emitter >= 0) continue;
            const tessera::Vec3 n = el[e].n;
            const int axis = std::abs(n.x) > 0.9f ? 0 : std::abs(n.y) > 0.9f ? 1 : 2;
            const int w = 2 * axis + ((axis == 0 ? n.x : axis == 1 ? n.y : n.z) > 0 ? 1 : 0);
            sa[w] += a.radiosity[2 * e].y * el[e].area;
            sb[w] += b.radiosity[2 * e].y * el[e].area;
        }
        std::vector<double> out;
        for (int w = 0; w < 6; ++w) out.push_back(sb[w] / sa[w] - 1.0);
        return out;
    }

private:
    static tessera::SceneDesc Describe(tessera::Color wall_albedo) {
        using tessera::Color;
        tessera::SceneDesc d;
        AddInwardBox(d, {0, 0, 0}, {2, 2, 2}, AddMaterial(d, wall_albedo, Color(0.f)));
        const uint32_t light = AddMaterial(d, Color(0.f), Color(10.f));
        AddQuad(d, {0.8f, 1.99f, 0.8f}, {1.2f, 1.99f, 0.8f}, {1.2f, 1.99f, 1.2f}, {0.8f, 1.99f, 1.2f}, light);
        const uint32_t grey = AddMaterial(d, Color(0.6f), Color(0.f));
        AddQuad(d, {0.5f, 1.f, 0.5f}, {0.5f, 1.f, 1.5f}, {1.5f, 1.f, 1.5f}, {1.5f, 1.f, 0.5f}, grey);
        return d;
    }
};

// The furnace: a closed 1 x 1.5 x 2 box of albedo rho whose every wall emits Le = 2, so
// B = E / (1 - rho) = pi Le / (1 - rho) everywhere; meshed at `element_size`.
struct FurnaceBox {
    static constexpr float kLe = 2.f;
    tessera::SceneDesc desc;
    tessera::Scene scene;
    tessera::RadiosityMesh mesh;
    tessera::RadiositySettings settings;  // element_size, 2 threads, tolerance 1e-4

    FurnaceBox(float rho, float element_size)
        : desc(Describe(rho)), scene(desc), mesh(scene, element_size) {
        settings.element_size = element_size;
        settings.tolerance = 1e-4f;
        settings.threads = 2;
    }
    // B on element e's front side (W m^-2) from a solution's reflected radiosity.
    double B(const std::vector<tessera::Color>& reflected, size_t e) const {
        return reflected[2 * e].y + mesh.elements()[e].emission[0].y;
    }

private:
    static tessera::SceneDesc Describe(float rho) {
        tessera::SceneDesc d;
        AddInwardBox(d, {0, 0, 0}, {1, 1.5f, 2}, AddMaterial(d, tessera::Color(rho), tessera::Color(kLe)));
        return d;
    }
};

}  // namespace tessera_test
