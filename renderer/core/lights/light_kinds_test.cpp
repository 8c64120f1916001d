// The light-kind list (light_kinds.h) against what the rest of Tessera relies on: the kind
// numbers a moving light's blob row carries (usd/lights.py asks the core for them, and a
// farm may hold blobs written before), the dispatch reaching each kind, and the emitter
// list a scene with one light of every kind builds from the kinds' AddEmitters.
#include <gtest/gtest.h>

#include <string>

#include "light_kinds.h"
#include "scene.h"
#include "scene_helpers.h"

using namespace tessera;

namespace {

// Written out by hand: the numbers SceneDesc::light_motion_kinds has always used.
struct Expected {
    const char* name;
    uint8_t number;
    bool moves;
};
constexpr Expected kExpected[] = {
    {"triangle", 0, false}, {"sphere", 1, true}, {"point", 2, true}, {"distant", 3, true}, {"dome", 4, true},
    {"portal", 5, false}};

}  // namespace

TEST(LightKinds, NumbersNamesAndMotionAreTheStableOnes) {
    EXPECT_EQ(uint8_t(kKindOf<TriangleLight>), 0);
    EXPECT_EQ(uint8_t(kKindOf<SphereLight>), 1);
    EXPECT_EQ(uint8_t(kKindOf<PointLight>), 2);
    EXPECT_EQ(uint8_t(kKindOf<DistantLight>), 3);
    EXPECT_EQ(uint8_t(kKindOf<DomeLight>), 4);
    EXPECT_EQ(uint8_t(kKindOf<PortalLight>), 5);
    const std::vector<LightKindInfo> infos = LightKindInfos();
    ASSERT_EQ(infos.size(), std::size(kExpected));
    for (const Expected& e : kExpected) {
        EXPECT_EQ(std::string(infos[e.number].name), e.name);
        EXPECT_EQ(infos[e.number].moves, e.moves) << e.name;
    }
    EXPECT_EQ(MovingKindNames(), "1 sphere, 2 point, 3 distant, 4 dome");
}

TEST(LightKinds, VisitReachesTheKindItsNumberNames) {
    for (const Expected& e : kExpected) {
        const std::string visited =
            VisitLightKind(LightKind(e.number), [](auto kind) -> std::string {
                return EmitterOf<typename decltype(kind)::type>::kName;
            });
        EXPECT_EQ(visited, e.name);
    }
}

// A floor lit by a sphere, a point, a delta and a cone distant light and a dome: the
// emitters come in list order (area emitters, then each kind's AddEmitters), with each
// kind's own answer to Infinite and Delta, and a moving light names its kind by number.
TEST(LightKinds, SceneBuildsOneEmitterPerLightInListOrder) {
    SceneDesc d = tessera_test::FloorScene(0.5f, 10.f);
    d.sphere_lights.push_back({Vec3(0, 3, 0), 0.5f, Color(1.f)});
    d.point_lights.push_back({Vec3(1, 2, 0), Color(2.f)});
    d.distant_lights.push_back({Vec3(0, -1, 0), 0.f, Color(1.f)});
    d.distant_lights.push_back({Vec3(0, -1, 0), 0.1f, Color(1.f)});
    d.dome_radiance = Color(0.25f);
    Scene scene(d);
    ASSERT_EQ(scene.num_emitters(), 5u);
    // sphere, point, delta distant, cone distant, dome
    const bool infinite[] = {false, false, true, true, true};
    const bool delta[] = {false, true, true, false, false};
    for (uint32_t i = 0; i < 5; ++i) {
        EXPECT_EQ(scene.IsInfiniteLight(i), infinite[i]) << "emitter " << i;
        EXPECT_EQ(scene.IsDeltaLight(i), delta[i]) << "emitter " << i;
    }
    // Position densities: 1 / area for the sphere, 1 for the point.
    EXPECT_NEAR(scene.EmissionPdfPosition(0), 1.f / (4.f * kPi * 0.25f), 1e-6f);
    EXPECT_EQ(scene.EmissionPdfPosition(1), 1.f);
    // Only kinds that move take a motion row; a triangle (kind 0) is refused by name.
    SceneDesc moving = d;
    moving.light_motion_kinds = {LightKind(0)};
    moving.light_motion_indices = {0};
    moving.light_motion_time_steps = {2};
    moving.light_motion_transforms.assign(24, 0.f);
    for (int s = 0; s < 2; ++s)
        for (int j = 0; j < 3; ++j) moving.light_motion_transforms[12 * s + 5 * j] = 1.f;
    try {
        Scene bad(moving);
        FAIL() << "a moving triangle light was accepted";
    } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("1 sphere, 2 point, 3 distant, 4 dome"), std::string::npos) << e.what();
    }
    moving.light_motion_kinds = {kKindOf<PointLight>};
    EXPECT_TRUE(Scene(moving).has_motion());
}
