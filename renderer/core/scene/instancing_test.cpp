// Embree instancing against flattening: the same prototypes placed by instance transforms
// (rotation, non-uniform scale, a mirror) or copied into the world mesh by the test's own
// transform code must give the same hits (point, normals, st, material, emission) and the
// same images, for textured and emissive prototypes alike.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "scene_helpers.h"

using namespace tessera;
using namespace tessera_test;

namespace {

struct Xform {
    double m[12];  // row-major 3x4: world = M (p, 1)
};

Xform Compose(double rx_deg, double ry_deg, Vec3 scale, Vec3 translate) {
    const double a = rx_deg * kPi / 180.0, b = ry_deg * kPi / 180.0;
    // R = Ry * Rx, M = R * diag(scale)
    const double rx[9] = {1, 0, 0, 0, std::cos(a), -std::sin(a), 0, std::sin(a), std::cos(a)};
    const double ry[9] = {std::cos(b), 0, std::sin(b), 0, 1, 0, -std::sin(b), 0, std::cos(b)};
    double r[9];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            r[3 * i + j] = 0;
            for (int k = 0; k < 3; ++k) r[3 * i + j] += ry[3 * i + k] * rx[3 * k + j];
        }
    const double s[3] = {scale.x, scale.y, scale.z};
    const double t[3] = {translate.x, translate.y, translate.z};
    Xform x;
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) x.m[4 * i + j] = r[3 * i + j] * s[j];
        x.m[4 * i + 3] = t[i];
    }
    return x;
}

// A prototype: a box with per-corner st and rounded corner normals, two materials.
MeshDesc BoxPrototype(uint32_t mat_a, uint32_t mat_b) {
    MeshDesc m;
    const float h = 0.5f;
    Vec3 p[8];
    for (int i = 0; i < 8; ++i) p[i] = Vec3(i & 1 ? h : -h, i & 2 ? h : -h, i & 4 ? h : -h);
    const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
    for (int q = 0; q < 6; ++q) {
        const uint32_t base = uint32_t(m.positions.size() / 3);
        for (int c = 0; c < 4; ++c) m.positions.insert(m.positions.end(), {p[quads[q][c]].x, p[quads[q][c]].y, p[quads[q][c]].z});
        m.indices.insert(m.indices.end(), {base, base + 1, base + 2, base, base + 2, base + 3});
        m.triangle_material.insert(m.triangle_material.end(), {q < 3 ? mat_a : mat_b, q < 3 ? mat_a : mat_b});
        const Vec2 st[4] = {{0.1f, 0.1f}, {0.9f, 0.15f}, {0.85f, 0.95f}, {0.05f, 0.8f}};
        for (int c : {0, 1, 2, 0, 2, 3}) {
            m.uvs.insert(m.uvs.end(), {st[c].x + 0.3f * q, st[c].y});
            Vec3 n = Normalize(p[quads[q][c]]);
            m.shading_normals.insert(m.shading_normals.end(), {n.x, n.y, n.z});
        }
    }
    return m;
}

// A small emitting quad facing -y.
MeshDesc LightPrototype(uint32_t mat) {
    MeshDesc m;
    m.positions = {-0.3f, 0, -0.3f, 0.3f, 0, -0.3f, 0.3f, 0, 0.3f, -0.3f, 0, 0.3f};
    m.indices = {0, 1, 2, 0, 2, 3};
    m.triangle_material = {mat, mat};
    m.uvs = {0, 0, 1, 0, 1, 1, 0, 0, 1, 1, 0, 1};
    for (int c = 0; c < 6; ++c) m.shading_normals.insert(m.shading_normals.end(), {0.f, -1.f, 0.f});
    return m;
}

// An n x n grid of quads (2 n^2 triangles) in the xz plane.
MeshDesc GridPrototype(int n) {
    MeshDesc m;
    for (int j = 0; j <= n; ++j)
        for (int i = 0; i <= n; ++i) m.positions.insert(m.positions.end(), {float(i) / n, 0.f, float(j) / n});
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
            const uint32_t a = uint32_t(j * (n + 1) + i), b = a + 1, c = a + uint32_t(n) + 2, e = a + uint32_t(n) + 1;
            m.indices.insert(m.indices.end(), {a, e, c, a, c, b});
            m.triangle_material.insert(m.triangle_material.end(), {0u, 0u});
        }
    return m;
}

// The test's own flattening: points by M, normals by M's inverse transpose, corners
// reversed under a mirroring M (as the USD translation's flatten does).
void Flatten(SceneDesc& d, const MeshDesc& proto, const Xform& x) {
    const double* m = x.m;
    const double det = m[0] * (m[5] * m[10] - m[6] * m[9]) - m[1] * (m[4] * m[10] - m[6] * m[8]) +
                       m[2] * (m[4] * m[9] - m[5] * m[8]);
    // inverse of the 3x3 by the adjugate; the normal matrix is its transpose
    double inv[9] = {m[5] * m[10] - m[6] * m[9], m[2] * m[9] - m[1] * m[10], m[1] * m[6] - m[2] * m[5],
                     m[6] * m[8] - m[4] * m[10], m[0] * m[10] - m[2] * m[8], m[2] * m[4] - m[0] * m[6],
                     m[4] * m[9] - m[5] * m[8], m[1] * m[8] - m[0] * m[9], m[0] * m[5] - m[1] * m[4]};
    for (double& v : inv) v /= det;
    const uint32_t base = uint32_t(d.positions.size() / 3);
    for (size_t i = 0; i < proto.positions.size(); i += 3) {
        const double p[3] = {proto.positions[i], proto.positions[i + 1], proto.positions[i + 2]};
        for (int r = 0; r < 3; ++r) d.positions.push_back(float(m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3]));
    }
    const size_t n_tri = proto.indices.size() / 3;
    const bool flip = det < 0;
    for (size_t t = 0; t < n_tri; ++t) {
        const int order[3] = {0, flip ? 2 : 1, flip ? 1 : 2};
        for (int c : order) {
            d.indices.push_back(base + proto.indices[3 * t + c]);
            if (!proto.uvs.empty()) d.uvs.insert(d.uvs.end(), {proto.uvs[6 * t + 2 * c], proto.uvs[6 * t + 2 * c + 1]});
            if (!proto.shading_normals.empty()) {
                const float* n = &proto.shading_normals[9 * t + 3 * c];
                for (int r = 0; r < 3; ++r)  // (inv^T n)_r = sum_k inv[k][r] n_k
                    d.shading_normals.push_back(float(inv[r] * n[0] + inv[3 + r] * n[1] + inv[6 + r] * n[2]));
            }
        }
        d.triangle_material.push_back(proto.triangle_material[t]);
    }
}

struct Pair {
    SceneDesc flat, inst;
};

Pair MakeScenes() {
    SceneDesc base;
    // Materials: a textured preview surface, a plain one, an emitter; a floor.
    MaterialParams tex_mat;
    tex_mat.roughness = 0.4f;
    Material textured{Color(0.5f), Color(0.f), false, tex_mat};
    textured.textures[kSlotDiffuseColor] = 0;
    base.materials.push_back(textured);                              // 0
    base.materials.push_back({Color(0.3f, 0.6f, 0.2f), Color(0.f)});  // 1
    base.materials.push_back({Color(0.f), Color(6.f, 5.f, 4.f)});     // 2
    base.materials.push_back({Color(0.5f), Color(0.f)});              // 3
    Image im;
    im.width = im.height = 4;
    im.channels = 3;
    for (int i = 0; i < 16; ++i) im.texels.insert(im.texels.end(), {0.1f + 0.05f * i, 0.9f - 0.05f * i, 0.3f});
    base.images.push_back(im);
    TextureDesc t;
    t.image = 0;
    t.output = TextureOutput::kRGB;
    base.textures.push_back(t);
    // The floor (world mesh, with uvs because the world mesh and the prototypes share a
    // layout: uvs present everywhere or nowhere per mesh).
    AddQuad(base, {-6, -2, -12}, {-6, -2, 2}, {6, -2, 2}, {6, -2, -12}, 3);
    for (int k = 0; k < 12; ++k) base.uvs.push_back(0.f);
    for (int k = 0; k < 6; ++k) base.shading_normals.insert(base.shading_normals.end(), {0.f, 1.f, 0.f});

    const MeshDesc box = BoxPrototype(0, 1), light = LightPrototype(2);
    const std::vector<std::pair<int, Xform>> placements = {
        {0, Compose(0, 30, Vec3(1.f), Vec3(-1.5f, -1.f, -5.f))},
        {0, Compose(20, -40, Vec3(0.5f, 1.2f, 0.8f), Vec3(1.5f, -0.5f, -6.f))},
        {0, Compose(0, 10, Vec3(-1.f, 1.f, 1.f), Vec3(0.f, -1.2f, -4.f))},  // a mirror
        {1, Compose(0, 0, Vec3(1.f), Vec3(0.f, 2.f, -5.f))},
        {1, Compose(0, 25, Vec3(-1.5f, 1.f, 1.f), Vec3(1.f, 2.5f, -6.f))},  // a mirrored light, still facing -y
    };
    Pair s{base, base};
    s.inst.prototypes = {box, light};
    for (const auto& [proto, x] : placements) {
        Flatten(s.flat, proto == 0 ? box : light, x);
        s.inst.instance_prototype.push_back(uint32_t(proto));
        for (double v : x.m) s.inst.instance_transforms.push_back(float(v));
    }
    s.flat.point_lights.push_back({Vec3(-2, 3, -3), Color(6.f)});
    s.inst.point_lights = s.flat.point_lights;
    return s;
}

Camera SceneCamera(uint32_t w, uint32_t h) {
    return Camera{{0, 0.5f, 1}, Vec3(1, 0, 0), Normalize(Vec3(0, 0.99f, -0.1f)), Normalize(Vec3(0, -0.1f, -0.99f)),
                  0.6f, 0.6f * h / w, w, h};
}

}  // namespace

TEST(Instancing, HitsMatchTheFlattenedScene) {
    Pair s = MakeScenes();
    Scene flat(s.flat), inst(s.inst);
    EXPECT_EQ(inst.num_triangles(), flat.num_triangles());
    EXPECT_EQ(inst.num_instances(), 5u);
    EXPECT_LT(inst.num_stored_triangles(), flat.num_stored_triangles());
    EXPECT_EQ(inst.num_emitters(), flat.num_emitters());  // every instance of the light is a light
    const int N = 48;
    int compared = 0, mismatched = 0, emitting = 0;
    for (int j = 0; j < N; ++j)
        for (int i = 0; i < N; ++i) {
            const Vec3 d = Normalize(Vec3((i + 0.5f) / N - 0.5f, 0.8f * ((j + 0.5f) / N - 0.5f) + 0.1f, -1.f));
            const Ray ray{{0, 0.5f, 1}, d};
            SurfaceHit a, b;
            const bool ha = flat.Intersect(ray, &a), hb = inst.Intersect(ray, &b);
            if (ha != hb || (ha && std::abs(a.t - b.t) > 1e-4f * a.t)) {
                ++mismatched;  // a ray grazing an edge may go either way in float
                continue;
            }
            if (!ha) continue;
            ++compared;
            EXPECT_NEAR(Length(a.p - b.p), 0.f, 1e-4f);
            EXPECT_GT(Dot(a.ng, b.ng), 0.9999f) << i << "," << j;
            EXPECT_GT(Dot(a.ns, b.ns), 0.9999f) << i << "," << j;
            EXPECT_NEAR(a.st.x, b.st.x, 1e-4f);
            EXPECT_NEAR(a.st.y, b.st.y, 1e-4f);
            EXPECT_EQ(flat.MaterialAt(a).albedo.x, inst.MaterialAt(b).albedo.x);
            const int32_t ea = flat.EmitterAt(a), eb = inst.EmitterAt(b);
            EXPECT_EQ(ea >= 0, eb >= 0);
            if (ea >= 0 && eb >= 0) {
                ++emitting;
                const Color la = flat.Emitted(ea, a, -d), lb = inst.Emitted(eb, b, -d);
                EXPECT_EQ(la.x, lb.x);
                EXPECT_FLOAT_EQ(flat.light_sampler().Pmf(uint32_t(ea)), inst.light_sampler().Pmf(uint32_t(eb)));
            }
            // The BSDF sees the same (textured) albedo.
            const BSDF fa = flat.BSDFAt(a, TransportMode::Radiance), fb = inst.BSDFAt(b, TransportMode::Radiance);
            EXPECT_NEAR(fa.Albedo().x, fb.Albedo().x, 1e-4f);
        }
    EXPECT_GT(compared, N * N / 8);
    EXPECT_GT(emitting, 0);
    EXPECT_LE(mismatched, N * N / 200);
    std::printf("compared %d, emitting %d, mismatched %d\n", compared, emitting, mismatched);
}

TEST(Instancing, ImagesMatchTheFlattenedSceneForEveryIntegrator) {
    Pair s = MakeScenes();
    Scene flat(s.flat), inst(s.inst);
    const uint32_t W = 24, H = 16;
    const Camera cam = SceneCamera(W, H);
    for (const char* integrator : {"path", "light", "bdpt"}) {
        RenderOptions opt{64, 9, 6, 2};
        opt.integrator = integrator;
        auto a = RenderResolved(flat, cam, opt), b = RenderResolved(inst, cam, opt);
        double ma = 0, mb = 0;
        for (size_t i = 0; i < size_t(W) * H; ++i) ma += a[4 * i], mb += b[4 * i];
        EXPECT_GT(ma, 0.02 * W * H);
        // Same samples, same geometry up to float rounding: the means agree far closer than
        // the noise (a different seed moves them by several percent here).
        EXPECT_NEAR(mb, ma, 0.01 * ma) << "integrator " << integrator;
        std::printf("integrator %s: flattened %.5f instanced %.5f\n", integrator, ma / (W * H), mb / (W * H));
    }
    // Negative control: moving one instance changes the image.
    s.inst.instance_transforms[3] += 0.7f;
    Scene moved(s.inst);
    auto a = RenderResolved(flat, cam, {64, 9, 6, 2}), c = RenderResolved(moved, cam, {64, 9, 6, 2});
    double diff = 0;
    for (size_t i = 0; i < size_t(W) * H; ++i) diff += std::abs(a[4 * i] - c[4 * i]);
    EXPECT_GT(diff, 0.5);
}

TEST(Instancing, BadInstancesAreRejectedWithAClearError) {
    Pair s = MakeScenes();
    SceneDesc d = s.inst;
    d.instance_prototype[1] = 7;
    try {
        Scene scene(d);
        ADD_FAILURE() << "an instance of a missing prototype was accepted";
    } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("prototype 7"), std::string::npos) << e.what();
    }
    d = s.inst;
    for (int k = 0; k < 3; ++k) d.instance_transforms[12 * 2 + k] = 0.f;  // first row zero: singular
    EXPECT_THROW(Scene scene(d), std::invalid_argument);
    d = s.inst;
    d.instance_transforms.pop_back();
    EXPECT_THROW(Scene scene(d), std::invalid_argument);
    d = s.inst;
    d.prototypes[0].triangle_material[0] = 99;
    try {
        Scene scene(d);
        ADD_FAILURE() << "a prototype material out of range was accepted";
    } catch (const std::invalid_argument& e) {
        EXPECT_NE(std::string(e.what()).find("prototype 0"), std::string::npos) << e.what();
    }
}

TEST(Instancing, EmbreeMemoryGrowsWithFlattenedCopiesNotWithInstances) {
    // 200 instances of one 800-triangle prototype cost far less Embree memory than 200 copies.
    MeshDesc box = GridPrototype(20);
    auto build = [&](bool instanced) {
        SceneDesc d;
        d.materials.push_back({Color(0.5f), Color(0.f)});
        if (instanced) d.prototypes = {box};
        for (int k = 0; k < 200; ++k) {
            Xform x = Compose(0, k, Vec3(1.f), Vec3(float(k % 20), 0.f, float(k / 20)));
            if (instanced) {
                d.instance_prototype.push_back(0);
                for (double v : x.m) d.instance_transforms.push_back(float(v));
            } else {
                Flatten(d, box, x);
            }
        }
        const int64_t before = EmbreeMemoryBytes();
        auto scene = std::make_unique<Scene>(d);
        return EmbreeMemoryBytes() - before;
    };
    const int64_t flat = build(false), inst = build(true);
    EXPECT_GT(flat, 0);
    EXPECT_GT(inst, 0);
    EXPECT_LT(inst * 10, flat) << "instanced " << inst << " bytes, flattened " << flat;
}

// World curves and instances share the top-level scene, each under its own geometry ID: the
// first instance once took the curves' ID and Embree refused every such scene ("error 3 in
// creating instances"), as a USD stage with BasisCurves beside a native instance is.
TEST(Instancing, WorldCurvesAndInstancesLiveTogether) {
    SceneDesc d;
    const uint32_t grey = AddMaterial(d, Color(0.5f), Color(0.f));
    MeshDesc quad;  // x, y in [-1, 1] at z = -3
    quad.positions = {-1, -1, -3, 1, -1, -3, 1, 1, -3, -1, 1, -3};
    quad.indices = {0, 1, 2, 0, 2, 3};
    quad.triangle_material = {grey, grey};
    d.prototypes = {quad};
    d.instance_prototype = {0};
    d.instance_transforms = {1, 0, 0, 2, 0, 1, 0, 0, 0, 0, 1, 0};  // moved to x in [1, 3]
    d.curve_points = {-2, -1, -3, 0.1f, -2, 1, -3, 0.1f};          // a strand at x = -2
    d.curve_segments = {0};
    d.curve_flags = {0};
    d.curve_material = {grey};
    Scene scene(d);
    SurfaceHit hit;
    ASSERT_TRUE(scene.Intersect(Ray{{2, 0, 0}, {0, 0, -1}}, &hit));
    EXPECT_EQ(hit.instance, 0u);
    EXPECT_NEAR(hit.t, 3.f, 1e-4f);
    ASSERT_TRUE(scene.Intersect(Ray{{-2, 0, 0}, {0, 0, -1}}, &hit));
    EXPECT_EQ(hit.geom_id, Scene::kCurveGeometry);
    EXPECT_NEAR(hit.t, 2.9f, 1e-2f);  // the strand's front, radius 0.1 in front of z = -3
    EXPECT_FALSE(scene.Intersect(Ray{{0, 0, 0}, {0, 0, -1}}, &hit));  // between them
}

