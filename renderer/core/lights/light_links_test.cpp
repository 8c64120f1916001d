#include "light_links.h"

#include <gtest/gtest.h>

#include "sampler.h"
#include "scene.h"
#include "scene_helpers.h"

using namespace tessera;

TEST(LightLinkTable, DefaultLinkLightsEverythingAndRowsSayTheRest) {
    // Two links over three groups: link 0 leaves group 1 unlit, link 1 lets group 2's
    // surfaces cast no shadow.
    const LightLinkTable t(3, {1, 0, 1, 1, 1, 1}, {1, 1, 1, 1, 1, 0});
    EXPECT_EQ(t.num_links(), 2u);
    EXPECT_TRUE(t.Illuminates(-1, 1) && t.CastsShadow(-1, 2) && !t.ExcludesShadows(-1));
    EXPECT_FALSE(t.Illuminates(0, 1));
    EXPECT_TRUE(t.Illuminates(0, 2));
    EXPECT_FALSE(t.ExcludesShadows(0));
    EXPECT_TRUE(t.ExcludesShadows(1));
    EXPECT_FALSE(t.CastsShadow(1, 2));
    EXPECT_THROW(t.Check(2, "light"), std::invalid_argument);
    EXPECT_THROW(LightLinkTable(2, {1, 0, 1}, {1, 0, 1}), std::invalid_argument);
    EXPECT_THROW(LightLinkTable(2, {1, 0}, {1}), std::invalid_argument);
}

namespace {

// Two point lights and two emissive quads over a floor of two link groups. Link 0 (the
// second point light and the second quad) leaves group 1 unlit.
SceneDesc LinkedLights(SceneDesc::LightSelection selection) {
    SceneDesc d;
    d.light_selection = selection;
    const uint32_t floor0 = tessera_test::AddMaterial(d, Color(0.5f), Color(0.f));
    const uint32_t floor1 = tessera_test::AddMaterial(d, Color(0.5f), Color(0.f));
    d.materials[floor1].link_group = 1;
    const uint32_t lamp = tessera_test::AddMaterial(d, Color(0.f), Color(2.f));
    const uint32_t linked_lamp = tessera_test::AddMaterial(d, Color(0.f), Color(3.f));
    d.materials[linked_lamp].light_link = 0;
    tessera_test::AddQuad(d, Vec3(-2, 0, -2), Vec3(0, 0, -2), Vec3(0, 0, 2), Vec3(-2, 0, 2), floor0);
    tessera_test::AddQuad(d, Vec3(0, 0, -2), Vec3(2, 0, -2), Vec3(2, 0, 2), Vec3(0, 0, 2), floor1);
    // Facing down (-y).
    tessera_test::AddQuad(d, Vec3(-1, 2, -1), Vec3(-1, 2, 0), Vec3(0, 2, 0), Vec3(0, 2, -1), lamp);
    tessera_test::AddQuad(d, Vec3(0, 2, 0), Vec3(0, 2, 1), Vec3(1, 2, 1), Vec3(1, 2, 0), linked_lamp);
    d.point_lights.push_back({Vec3(0, 3, 0), Color(5.f)});
    d.point_lights.push_back({Vec3(1, 3, 0), Color(7.f)});
    d.point_light_link = {-1, 0};
    d.light_links = LightLinkTable(2, {1, 0}, {1, 1});
    return d;
}

}  // namespace

// Next event estimation picks, for a point of each group, only the lights that illuminate
// it, with exactly the probability LightPmf states for that group; the probabilities of
// the group's lights sum to 1 (the power tables) or at most 1 (the BVH). Both selectors.
TEST(LightLinks, EachGroupChoosesOnlyItsLightsWithTheStatedProbability) {
    for (auto selection : {SceneDesc::LightSelection::kPower, SceneDesc::LightSelection::kBVH}) {
        const Scene scene(LinkedLights(selection));
        ASSERT_TRUE(scene.has_light_links());
        EXPECT_EQ(scene.num_linked_lights(), 1u);
        EXPECT_EQ(scene.uses_light_bvh(), selection == SceneDesc::LightSelection::kBVH);
        const Vec3 n(0, 1, 0);
        for (uint32_t group : {0u, 1u}) {
            const Vec3 p(group == 0 ? -1.f : 1.f, 0.f, 0.f);
            double sum = 0.0;
            for (uint32_t e = 0; e < scene.num_emitters(); ++e) {
                const float pmf = scene.LightPmf(p, n, e, group);
                if (!scene.Illuminates(e, group)) EXPECT_EQ(pmf, 0.f) << "emitter " << e << " group " << group;
                sum += pmf;
            }
            if (selection == SceneDesc::LightSelection::kPower) EXPECT_NEAR(sum, 1.0, 1e-5);
            else EXPECT_LE(sum, 1.0 + 1e-5);
            EXPECT_GT(sum, 0.5);
            for (int i = 0; i < 4096; ++i) {
                PixelSampler s(1, uint64_t(i), 0);
                uint32_t light = 0;
                float pmf = 0.f;
                if (!scene.SampleLight(s.Get1D(), p, n, &light, &pmf, group)) continue;
                ASSERT_TRUE(scene.Illuminates(light, group)) << "light " << light << " group " << group;
                ASSERT_FLOAT_EQ(pmf, scene.LightPmf(p, n, light, group));
            }
        }
        // Without a group every light is a candidate, as in a scene without links.
        double all = 0.0;
        for (uint32_t e = 0; e < scene.num_emitters(); ++e) all += scene.LightPmf(Vec3(1, 0, 0), Vec3(0, 1, 0), e);
        EXPECT_GT(all, 0.5);
    }
}

TEST(LightLinks, BadLinksAreRefused) {
    SceneDesc d = LinkedLights(SceneDesc::LightSelection::kAuto);
    d.point_light_link = {-1, 1};  // there is one link
    EXPECT_THROW(Scene{d}, std::invalid_argument);
    d = LinkedLights(SceneDesc::LightSelection::kAuto);
    d.materials[0].link_group = 2;  // there are two groups
    EXPECT_THROW(Scene{d}, std::invalid_argument);
}
