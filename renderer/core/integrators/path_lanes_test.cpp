// The lane kernel (path_lanes.h) against the scalar kernel it must equal to the bit: any
// lane width, any grouping of samples into lanes (tile size, spp), any thread count.
#include <gtest/gtest.h>

#include <cstring>
#include <memory>
#include <vector>

#include "integrator.h"
#include "path_lanes.h"
#include "render.h"
#include "scene_helpers.h"

using namespace tessera;
using namespace tessera_test;

namespace {

// A Cornell-like closed box: coloured walls, a block, a triangle light under the ceiling.
SceneDesc LitBox(float light_scale = 1.f) {
    SceneDesc d;
    const uint32_t white = AddMaterial(d, Color(0.73f), Color(0.f));
    const uint32_t red = AddMaterial(d, Color(0.65f, 0.05f, 0.05f), Color(0.f));
    const uint32_t light = AddMaterial(d, Color(0.f), Color(17.f, 12.f, 4.f) * light_scale);
    AddInwardBox(d, {-1, -1, -1}, {1, 1, 1}, white);
    AddQuad(d, {-1, -1, -1}, {-1, 1, -1}, {-1, 1, 1}, {-1, -1, 1}, red);  // x = -1, facing +x
    AddQuad(d, {-0.6f, -1, -0.2f}, {-0.6f, -0.2f, -0.2f}, {0.f, -0.2f, -0.2f}, {0.f, -1, -0.2f}, white);
    AddQuad(d, {-0.25f, 0.99f, -0.25f}, {0.25f, 0.99f, -0.25f}, {0.25f, 0.99f, 0.25f}, {-0.25f, 0.99f, 0.25f},
            light);
    return d;
}

// An open floor under a dome and a point light: escaped paths and a delta light.
SceneDesc DomeFloor() {
    SceneDesc d = FloorScene(0.5f, 3.f);
    const uint32_t m = AddMaterial(d, Color(0.2f, 0.6f, 0.3f), Color(0.f));
    AddQuad(d, {-0.5f, 0.5f, -0.5f}, {0.5f, 0.5f, -0.5f}, {0.5f, 0.5f, 0.5f}, {-0.5f, 0.5f, 0.5f}, m);
    d.dome_radiance = Color(0.4f, 0.5f, 0.9f);
    PointLight p;
    p.position = Vec3(1.f, 2.f, 0.5f);
    p.intensity = Color(3.f);
    d.point_lights.push_back(p);
    return d;
}

std::vector<float> RenderWith(const Scene& scene, const Camera& cam, float lanes, uint32_t tile, int threads,
                              uint32_t spp = 13) {
    RenderOptions o;
    o.spp = spp;  // not a multiple of the lane width: lanes regenerate across ragged ends
    o.seed = 7;
    o.threads = threads;
    o.integrator_params["lanes"] = lanes;
    std::vector<float> img(size_t(cam.width) * cam.height * 4);
    for (uint32_t y = 0; y < cam.height; y += tile)
        for (uint32_t x = 0; x < cam.width; x += tile) {
            const TileRect t{x, y, std::min(tile, cam.width - x), std::min(tile, cam.height - y)};
            const std::vector<float> part = Render(scene, cam, o, t);
            for (uint32_t r = 0; r < t.height; ++r)
                std::memcpy(&img[4 * ((size_t(y) + r) * cam.width + x)], &part[4 * size_t(r) * t.width],
                            4 * sizeof(float) * t.width);
        }
    return img;
}

bool SameBits(const std::vector<float>& a, const std::vector<float>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

bool TakesLanes(const Scene& scene, float lanes) {
    IntegratorSettings s;
    s.params["lanes"] = lanes;
    return Integrator::Create("path", s, scene)->samples_in_batches();
}

}  // namespace

// The scalar kernel's image (lanes 0) is the reference: every lane width, tile size and
// thread count gives its bits. The check can fail: the lane kernel really runs (it is
// chosen for these scenes), and a light 0.1 % brighter changes the bits.
TEST(PathLanes, EveryLaneWidthTileAndThreadCountGivesTheScalarKernelsBits) {
    for (const bool open : {false, true}) {
        const Scene scene(open ? DomeFloor() : LitBox());
        const Camera cam = open ? LookDownMinusZ({0, 1.5f, 4}, 20, 14, 0.6f) : LookDownMinusZ({0, 0, 0.95f}, 20, 14, 0.9f);
        ASSERT_TRUE(LaneKernelApplies(scene));
        for (float lanes : {1.f, 4.f, 8.f, -1.f}) EXPECT_TRUE(TakesLanes(scene, lanes));
        EXPECT_FALSE(TakesLanes(scene, 0.f));
        EXPECT_FALSE(Integrator::Create("path", {}, scene)->samples_in_batches());  // opt-in
        const std::vector<float> reference = RenderWith(scene, cam, 0.f, 64, 1);
        double sum = 0;
        for (size_t i = 0; i < reference.size(); i += 4) sum += reference[i];
        ASSERT_GT(sum, 0.0);  // a lit image, not a black one
        for (float lanes : {1.f, 4.f, 8.f})
            for (uint32_t tile : {64u, 7u})
                for (int threads : {1, 2})
                    EXPECT_TRUE(SameBits(reference, RenderWith(scene, cam, lanes, tile, threads)))
                        << (open ? "dome floor" : "lit box") << ", lanes " << lanes << ", tile " << tile
                        << ", threads " << threads;
        if (!open) {
            const Scene brighter(LitBox(1.001f));
            EXPECT_FALSE(SameBits(reference, RenderWith(brighter, cam, 8.f, 64, 2)));
        }
    }
}

// A pixel's samples split over render calls (progressive passes, farm tiles of a sample
// range) sum the same estimates as one call: sample s is sample s whatever its batch.
TEST(PathLanes, SampleRangesSplitAnywhereGiveTheSameEstimates) {
    const Scene scene(LitBox());
    const Camera cam = LookDownMinusZ({0, 0, 0.95f}, 6, 5, 0.9f);
    RenderOptions o;
    o.seed = 3;
    o.integrator_params["lanes"] = 8;
    const TileRect t{0, 0, 6, 5};
    std::vector<float> whole(6 * 5 * 4), lanes_a(6 * 5 * 4), lanes_b(6 * 5 * 4), scalar_a(6 * 5 * 4);
    o.spp = 5;
    o.sample_start = 3;
    RenderTile(scene, cam, o, t, lanes_a.data());
    o.integrator_params["lanes"] = 0;
    RenderTile(scene, cam, o, t, scalar_a.data());
    EXPECT_TRUE(SameBits(lanes_a, scalar_a));
    o.sample_start = 8;
    o.integrator_params["lanes"] = 4;
    RenderTile(scene, cam, o, t, lanes_b.data());
    o.integrator_params["lanes"] = 0;
    RenderTile(scene, cam, o, t, whole.data());
    EXPECT_TRUE(SameBits(lanes_b, whole));
}

// Scenes the lane kernel does not render take the scalar kernel whatever `lanes` says,
// and a width it has not is refused by name.
TEST(PathLanes, OtherScenesFallBackAndBadWidthsAreRefused) {
    SceneDesc d = LitBox();
    Material mirror{Color(0.9f), Color(0.f), false, std::nullopt};
    d.materials.push_back(mirror);
    MaterialParams p;
    p.metallic = 1.f;
    p.roughness = 0.f;
    d.materials.back().preview = p;
    AddQuad(d, {0.2f, -1, 0.2f}, {0.8f, -1, 0.2f}, {0.8f, -0.4f, 0.2f}, {0.2f, -0.4f, 0.2f},
            uint32_t(d.materials.size() - 1));
    const Scene glossy(d);
    EXPECT_FALSE(LaneKernelApplies(glossy));
    EXPECT_FALSE(TakesLanes(glossy, 8.f));
    IntegratorSettings s;
    s.params["lanes"] = 3.f;
    const Scene box(LitBox());
    EXPECT_THROW(Integrator::Create("path", s, box), std::invalid_argument);
}
