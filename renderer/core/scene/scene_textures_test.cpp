// Textured materials, normal maps, cutout opacity textures and textured emitters in the
// scene, against closed forms: a Lambertian-like UsdPreviewSurface (ior 1, seen and lit
// along the normal, so Schlick's Fresnel is exactly 0) reflects albedo / pi * E.
#include <gtest/gtest.h>

#include <cmath>

#include "scene_helpers.h"

using namespace tessera;
using namespace tessera_test;

namespace {

uint32_t AddPreviewMaterial(SceneDesc& d, const MaterialParams& p, Color emission = Color(0.f),
                            std::array<int32_t, kNumTextureSlots> textures = NoTextures()) {
    Material m{p.diffuse_color, emission, false, p};
    m.textures = textures;
    d.materials.push_back(m);
    return uint32_t(d.materials.size() - 1);
}

// Quad a-b-c-e with per-corner st, as two triangles (a, b, c) and (a, c, e).
void AddQuadST(SceneDesc& d, Vec3 a, Vec3 b, Vec3 c, Vec3 e, uint32_t material, Vec2 ta, Vec2 tb, Vec2 tc, Vec2 te) {
    AddQuad(d, a, b, c, e, material);
    for (Vec2 t : {ta, tb, tc, ta, tc, te}) d.uvs.insert(d.uvs.end(), {t.x, t.y});
}

Image RGBImage(uint32_t w, uint32_t h, const std::vector<Color>& texels, bool srgb = false) {
    Image im;
    im.width = w;
    im.height = h;
    im.channels = 3;
    im.srgb = srgb;
    for (Color c : texels) im.texels.insert(im.texels.end(), {c.x, c.y, c.z});
    return im;
}

TextureDesc RGBTexture(int32_t image, WrapMode wrap = WrapMode::kRepeat) {
    TextureDesc t;
    t.image = image;
    t.wrap_s = t.wrap_t = wrap;
    t.output = TextureOutput::kRGB;
    return t;
}

MaterialParams LambertLike(Color diffuse) {
    MaterialParams p;
    p.diffuse_color = diffuse;
    p.ior = 1.f;  // F0 = 0: at normal incidence the specular lobe and the Fresnel weights vanish
    return p;
}

// A floor quad (y = 0, facing +y, 2 x 2) whose st puts the origin at (0.25, 0.25):
// s grows with x, t grows toward -z.
void AddFloorST(SceneDesc& d, uint32_t material) {
    auto st = [](float x, float z) { return Vec2{(x + 1.f) / 2.f - 0.25f, (1.f - z) / 2.f - 0.25f}; };
    AddQuadST(d, {-1, 0, -1}, {-1, 0, 1}, {1, 0, 1}, {1, 0, -1}, material, st(-1, -1), st(-1, 1), st(1, 1),
              st(1, -1));
}

// A 4x4 image whose lower-left 2x2 block is `block` and the rest a different colour, so
// st (0.25, 0.25) and its bilinear neighbourhood see only `block`.
Image BlockImage(Color block, bool srgb = false) {
    std::vector<Color> t(16, Color(0.05f, 0.9f, 0.6f));
    for (int y = 2; y < 4; ++y)
        for (int x = 0; x < 2; ++x) t[y * 4 + x] = block;
    return RGBImage(4, 4, t, srgb);
}

double RenderFloorCentre(const SceneDesc& d) {
    Scene scene(d);
    auto px = Render(scene, LookDownAtOrigin(1.f), {4, 0, 1, 1}, {0, 0, 4, 4});
    return MeanChannel(px, 0);
}

}  // namespace

TEST(Textures, TexturedPlaneIsTexelAlbedoTimesIrradiance) {
    const float E = 3.f;
    for (bool srgb : {false, true}) {
        SceneDesc d;
        std::array<int32_t, kNumTextureSlots> slots = NoTextures();
        slots[kSlotDiffuseColor] = 0;
        const Color block = srgb ? Color(128.f / 255.f, 0.2f, 0.1f) : Color(0.8f, 0.4f, 0.1f);
        d.images.push_back(BlockImage(block, srgb));
        d.textures.push_back(RGBTexture(0));
        AddFloorST(d, AddPreviewMaterial(d, LambertLike(Color(0.18f)), Color(0.f), slots));
        d.distant_lights.push_back({Vec3(0, -1, 0), 0.f, Color(E)});
        const double albedo = srgb ? 0.215861 : 0.8;  // sRGB 128 decodes to 0.215861
        EXPECT_NEAR(RenderFloorCentre(d), albedo / kPi * E, 1e-4 * albedo) << "srgb " << srgb;
        // Negative control: the untextured material gives its constant albedo.
        d.materials[0].textures = NoTextures();
        EXPECT_NEAR(RenderFloorCentre(d), 0.18 / kPi * E, 1e-4);
    }
}

TEST(Textures, TexturedRoughnessAndMetallicReachTheBSDF) {
    // metallic textured to 1 turns the floor into a conductor of F0 = diffuse colour: seen
    // and lit along the normal, a rough conductor reflects differently from the diffuse.
    SceneDesc d;
    std::array<int32_t, kNumTextureSlots> slots = NoTextures();
    slots[kSlotMetallic] = 0;
    d.images.push_back(BlockImage(Color(1.f)));
    TextureDesc t = RGBTexture(0);
    t.output = TextureOutput::kR;
    d.textures.push_back(t);
    AddFloorST(d, AddPreviewMaterial(d, LambertLike(Color(0.5f)), Color(0.f), slots));
    d.distant_lights.push_back({Vec3(0, -1, 0), 0.f, Color(1.f)});
    SceneDesc constant = d;
    constant.materials[0].textures = NoTextures();
    constant.materials[0].preview->metallic = 1.f;
    EXPECT_NEAR(RenderFloorCentre(d), RenderFloorCentre(constant), 1e-6);
    constant.materials[0].preview->metallic = 0.f;
    EXPECT_GT(std::abs(RenderFloorCentre(d) - RenderFloorCentre(constant)), 0.01);
}

TEST(NormalMaps, FlatMapChangesNothingAndATiltedOneShadesLikeTiltedGeometry) {
    const float E = 2.f, a = 0.5f, tilt = 0.5235988f;  // 30 degrees
    auto floor = [&](std::optional<Color> encoded) {
        SceneDesc d;
        std::array<int32_t, kNumTextureSlots> slots = NoTextures();
        if (encoded) {
            slots[kSlotNormal] = 0;
            d.images.push_back(RGBImage(1, 1, {*encoded}));
            TextureDesc t = RGBTexture(0);
            t.scale = {2.f, 2.f, 2.f, 1.f};  // the spec's normal-map decoding
            t.bias = {-1.f, -1.f, -1.f, 0.f};
            d.textures.push_back(t);
        }
        AddFloorST(d, AddPreviewMaterial(d, LambertLike(Color(a)), Color(0.f), slots));
        d.distant_lights.push_back({Vec3(0, -1, 0), 0.f, Color(E)});
        return RenderFloorCentre(d);
    };
    const double plain = floor(std::nullopt);
    EXPECT_NEAR(plain, a / kPi * E, 1e-5);
    EXPECT_NEAR(floor(Color(0.5f, 0.5f, 1.f)), plain, 1e-6);
    // Tangent space: +x along dp/ds (world +x here), +z the normal. Tilted 30 degrees
    // toward +x: the light and the camera (both along the normal) are 30 degrees off it.
    const Color tilted(0.5f + 0.5f * std::sin(tilt), 0.5f, 0.5f + 0.5f * std::cos(tilt));
    const double c = std::cos(tilt), fresnel = std::pow(1.0 - c, 5);  // Schlick, F0 = 0
    const double expected = a / kPi * E * c * (1.0 - fresnel) * (1.0 - fresnel);
    EXPECT_NEAR(floor(tilted), expected, 1e-4 * expected);
    // The same tilt made with geometry (a quad whose normal is (sin, cos, 0)).
    SceneDesc g;
    const Vec3 e1(std::cos(tilt), -std::sin(tilt), 0.f), e2(0, 0, 1);
    AddQuad(g, -e1 - e2, -e1 + e2, e1 + e2, e1 - e2, AddPreviewMaterial(g, LambertLike(Color(a))));
    g.distant_lights.push_back({Vec3(0, -1, 0), 0.f, Color(E)});
    EXPECT_NEAR(RenderFloorCentre(g), expected, 1e-4 * expected);
}

TEST(NormalMaps, LightAndBidirectionalTransportAgreeWithPathTracing) {
    // The perturbed normal is a shading normal like any other: the importance correction
    // must keep light tracing in agreement (seen obliquely, where it matters).
    SceneDesc d;
    std::array<int32_t, kNumTextureSlots> slots = NoTextures();
    slots[kSlotNormal] = 0;
    std::vector<Color> bumps;
    for (int i = 0; i < 16; ++i) bumps.push_back(Color(0.5f + 0.3f * std::sin(float(i)), 0.5f + 0.3f * std::cos(1.7f * i), 1.f));
    d.images.push_back(RGBImage(4, 4, bumps));
    TextureDesc t = RGBTexture(0);
    t.scale = {2.f, 2.f, 2.f, 1.f};
    t.bias = {-1.f, -1.f, -1.f, 0.f};
    d.textures.push_back(t);
    AddFloorST(d, AddPreviewMaterial(d, LambertLike(Color(0.6f)), Color(0.f), slots));
    d.point_lights.push_back({Vec3(0.5f, 2.f, 0.3f), Color(4.f)});
    Scene scene(d);
    const uint32_t W = 8, H = 8;
    Vec3 fwd = Normalize(Vec3(-1.f, -0.8f, 0.f));
    Camera cam{{1.5f, 1.2f, 0}, Vec3(0, 0, -1), Normalize(Cross(Vec3(0, 0, -1), fwd)), fwd, 0.2f, 0.2f, W, H};
    // 16 runs per integrator, Welch t: detects 2 % (asserted, with a negative control).
    ExpectPathLightBDPTAgree(scene, cam, RenderOptions{1024, 3, 1, 2}, 0, 16, 0.01);
}

TEST(Textures, CutoutOpacityTextureLetsRaysThroughWhereItIsBelowTheThreshold) {
    for (bool textured : {true, false}) {
        SceneDesc d;
        std::array<int32_t, kNumTextureSlots> slots = NoTextures();
        slots[kSlotOpacity] = textured ? 0 : -1;
        Image im = RGBImage(2, 1, {Color(0.f), Color(1.f)});  // left transparent, right opaque
        d.images.push_back(im);
        TextureDesc t = RGBTexture(0, WrapMode::kClamp);
        t.output = TextureOutput::kR;
        d.textures.push_back(t);
        MaterialParams p = LambertLike(Color(0.5f));
        p.opacity_threshold = 0.5f;
        AddQuadST(d, {-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1}, AddPreviewMaterial(d, p, Color(0.f), slots),
                  {0, 0}, {1, 0}, {1, 1}, {0, 1});
        AddQuadST(d, {-5, -5, -2}, {5, -5, -2}, {5, 5, -2}, {-5, 5, -2}, AddMaterial(d, Color(0.f), Color(1.f)),
                  {0, 0}, {0, 0}, {0, 0}, {0, 0});
        Scene scene(d);
        SurfaceHit hit;
        const Vec3 left = Normalize(Vec3(-0.5f, 0, -1)), right = Normalize(Vec3(0.5f, 0, -1));
        ASSERT_TRUE(scene.Intersect({Vec3(0.f), right}, &hit));
        EXPECT_NEAR(hit.p.z, -1.f, 1e-5f);
        ASSERT_TRUE(scene.Intersect({Vec3(0.f), left}, &hit));
        EXPECT_NEAR(hit.p.z, textured ? -2.f : -1.f, 1e-5f) << "textured " << textured;
        EXPECT_EQ(scene.Occluded(Vec3(0.f), left, 1.5f), !textured);
        EXPECT_TRUE(scene.Occluded(Vec3(0.f), right, 1.5f));
    }
}

// Presence mode (opacity_threshold < 0, the translator's mark for a partial opacity that
// does not refract): a hit is a surface with probability opacity, for camera and shadow
// rays alike, and the rest pass straight on. Over 100,000 rays through a quad of opacity
// 0.3 the pass-through share is 0.7 within 4 binomial sigmas (0.0058), a bound that a 2 %
// error (0.014) exceeds, which the negative control checks.
TEST(Textures, PresenceModeLetsOneMinusOpacityOfRaysThrough) {
    SceneDesc d;
    MaterialParams p = LambertLike(Color(0.5f));
    p.opacity = 0.3f;
    p.opacity_threshold = -1.f;
    AddQuadST(d, {-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1}, AddPreviewMaterial(d, p, Color(0.f), NoTextures()),
              {0, 0}, {1, 0}, {1, 1}, {0, 1});
    AddQuadST(d, {-5, -5, -2}, {5, -5, -2}, {5, 5, -2}, {-5, 5, -2}, AddMaterial(d, Color(0.f), Color(1.f)),
              {0, 0}, {0, 0}, {0, 0}, {0, 0});
    Scene scene(d);
    const int n = 100000;
    int through = 0, unoccluded = 0;
    for (int i = 0; i < n; ++i) {
        // A stratified spread of directions through the quad (|x|, |y| < 0.9 at z = -1).
        const float x = -0.9f + 1.8f * ((i % 317) + 0.5f) / 317.f;
        const float y = -0.9f + 1.8f * ((i / 317) + 0.5f) / float(n / 317 + 1);
        const Vec3 dir = Normalize(Vec3(x, y, -1.f));
        SurfaceHit hit;
        ASSERT_TRUE(scene.Intersect({Vec3(0.f), dir}, &hit));
        through += hit.p.z < -1.5f;
        unoccluded += !scene.Occluded(Vec3(0.f), dir, 1.9f);  // before the backdrop (t >= 2)
    }
    const double sigma = std::sqrt(0.7 * 0.3 / n);
    const double f = double(through) / n, g = double(unoccluded) / n;
    EXPECT_LT(std::abs(f - 0.7), 4 * sigma) << f;
    EXPECT_LT(std::abs(g - 0.7), 4 * sigma) << g;
    EXPECT_GT(std::abs(f - 0.7 * 1.02), 4 * sigma) << "negative control: a 2 % error must show";
    // Where it is a surface, the BSDF is opaque (no glass lobe).
    EXPECT_FALSE(MakePreviewSurfaceBSDF(p, TransportMode::Radiance).HasTransmission());
}

namespace {

// Two emitting quads side by side at z = -1 facing the camera (+z): the left one's st
// lies in texel 0 of a 2x1 emissive texture (2.0), the right one's in texel 1 (6.0); the
// material's own emission (1.0) is what the texture replaces.
SceneDesc TexturedEmitters(bool textured) {
    SceneDesc d;
    std::array<int32_t, kNumTextureSlots> slots = NoTextures();
    slots[kSlotEmissiveColor] = textured ? 0 : -1;
    d.images.push_back(RGBImage(2, 1, {Color(2.f), Color(6.f)}));
    d.textures.push_back(RGBTexture(0, WrapMode::kClamp));
    const uint32_t m = AddPreviewMaterial(d, LambertLike(Color(0.f)), Color(1.f), slots);
    AddQuadST(d, {-1, -1, -1}, {0, -1, -1}, {0, 1, -1}, {-1, 1, -1}, m, {0, 0}, {0.2f, 0}, {0.2f, 1}, {0, 1});
    AddQuadST(d, {0, -1, -1}, {1, -1, -1}, {1, 1, -1}, {0, 1, -1}, m, {0.8f, 0}, {1, 0}, {1, 1}, {0.8f, 1});
    return d;
}

}  // namespace

TEST(Textures, EmissiveTextureIsTheRadianceSeen) {
    Scene scene(TexturedEmitters(true));
    const uint32_t W = 8, H = 4;
    auto px = Render(scene, LookDownMinusZ({0, 0, 0}, W, H), {4, 0, 4, 1}, {0, 0, W, H});
    for (uint32_t y = 0; y < H; ++y)
        for (uint32_t x = 0; x < W; ++x) EXPECT_FLOAT_EQ(px[4 * (y * W + x)], x < W / 2 ? 2.f : 6.f) << x;
}

TEST(Textures, EmissiveTextureLightsTheSceneAlikeForEveryIntegrator) {
    // The textured emitters face a floor: path tracing (hits and light sampling), light
    // tracing and BDPT (emission sampling) must see the texture's radiance, and the result
    // must differ from the untextured material's (negative control).
    auto scene_desc = [](bool textured) {
        SceneDesc d = TexturedEmitters(textured);
        // Turn the emitters to face down (-y) over a floor at y = -1.
        // (x, y, z) -> (x, 1, y): the quads hang at height 1 and, wound as before, face -y.
        for (size_t i = 0; i < d.positions.size(); i += 3) {
            d.positions[i + 2] = d.positions[i + 1];
            d.positions[i + 1] = 1.f;
        }
        const uint32_t grey = AddMaterial(d, Color(0.5f), Color(0.f));
        AddQuadST(d, {-2, -1, -2}, {-2, -1, 2}, {2, -1, 2}, {2, -1, -2}, grey, {0, 0}, {0, 0}, {0, 0}, {0, 0});
        return d;
    };
    Scene scene(scene_desc(true)), plain(scene_desc(false));
    const uint32_t W = 8, H = 8;
    Camera cam{{0, 0.5f, 3}, Vec3(1, 0, 0), Normalize(Vec3(0, 0.96f, -0.28f)), Normalize(Vec3(0, -0.28f, -0.96f)),
               0.5f, 0.5f, W, H};
    const double untextured = MeanChannel(RenderResolved(plain, cam, {512, 7, 4, 2}), 0);
    // Texels 2 and 6 against a constant 1: the path mean exceeds twice the untextured one.
    // 16 runs per integrator, Welch t: detects 2 % (asserted, with a negative control).
    ExpectPathLightBDPTAgree(scene, cam, RenderOptions{128, 7, 4, 2}, 0, 16, 2.0 * untextured);
}

TEST(Textures, BadTextureInputIsRejectedWithAClearError) {
    SceneDesc d;
    std::array<int32_t, kNumTextureSlots> slots = NoTextures();
    slots[kSlotRoughness] = 3;  // no such texture
    AddFloorST(d, AddPreviewMaterial(d, LambertLike(Color(0.5f)), Color(0.f), slots));
    try {
        Scene s(d);
        ADD_FAILURE() << "a texture index out of range was accepted";
    } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("texture 3"), std::string::npos) << e.what();
    }
    d.materials[0].textures = NoTextures();
    d.uvs[5] = std::nanf("");
    try {
        Scene s(d);
        ADD_FAILURE() << "a NaN st was accepted";
    } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("non-finite st"), std::string::npos) << e.what();
    }
    d.uvs.pop_back();
    EXPECT_THROW(Scene s(d), std::invalid_argument);  // wrong uv count
}

// The footprint a camera pixel has on the floor (s = x / 2 + c, t = -z / 2 + c): seen head
// on from height h, a square of side h * angle in both directions; seen at an angle theta
// from the normal at distance D, D * angle across the ray and D * angle / cos(theta) along
// the ray's trace on the floor (z here). st halves each (the floor maps 2 units to 1).
TEST(Textures, FootprintIsThePixelConeOnTheSurface) {
    SceneDesc d;
    std::array<int32_t, kNumTextureSlots> slots = NoTextures();
    slots[kSlotDiffuseColor] = 0;
    d.images.push_back(BlockImage(Color(0.5f)));
    d.textures.push_back(RGBTexture(0));
    AddFloorST(d, AddPreviewMaterial(d, LambertLike(Color(0.18f)), Color(0.f), slots));
    Scene scene(d);
    const float h = 0.5f, angle = 1e-3f;
    TextureFootprintCamera cam;
    cam.origin = {0.f, h, 0.f};
    cam.forward = {0.f, -1.f, 0.f};
    cam.pixel_angle = angle;
    auto length = [](Vec2 v) { return std::sqrt(v.x * v.x + v.y * v.y); };
    auto footprint_towards = [&](Vec3 target) {
        SurfaceHit hit;
        EXPECT_TRUE(scene.Intersect({cam.origin, Normalize(target - cam.origin)}, &hit));
        return scene.FootprintAt(hit);
    };
    EXPECT_EQ(length(footprint_towards({0.f, 0.f, 0.f}).dx), 0.f);  // no camera: a point lookup
    const TextureFootprintScope scope(&cam);
    const TextureFootprint head_on = footprint_towards({0.f, 0.f, 0.f});
    EXPECT_NEAR(length(head_on.dx), 0.5f * h * angle, 1e-4f * h * angle);
    EXPECT_NEAR(length(head_on.dy), 0.5f * h * angle, 1e-4f * h * angle);
    const float z = -0.8f, D = std::sqrt(h * h + z * z), cos_theta = h / D;
    const TextureFootprint oblique = footprint_towards({0.f, 0.f, z});
    EXPECT_NEAR(oblique.dx.x, 0.f, 1e-7f);  // along the ray's trace: t only
    EXPECT_NEAR(std::abs(oblique.dx.y), 0.5f * D * angle / cos_theta, 1e-4f * D * angle / cos_theta);
    EXPECT_NEAR(std::abs(oblique.dy.x), 0.5f * D * angle, 1e-4f * D * angle);  // across: s only
    EXPECT_NEAR(oblique.dy.y, 0.f, 1e-7f);
}
