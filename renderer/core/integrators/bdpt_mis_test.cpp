// BDPT's MIS weights are a partition of unity: for a given full path, the power-heuristic
// weights of all the strategies (s, t) that can generate it sum to 1, and each equals the
// power heuristic computed directly from the full-path densities p_{s,t} (a product of
// per-vertex densities, not the ratio recurrence bdpt.cpp uses).
//
// Strategies that cannot generate a path get weight 0 (their Connect returns black, so
// their MISWeight is never applied): a delta vertex (ideal mirror, glass) cannot be an
// endpoint of a connection, a delta light (a point) cannot be hit (s = 0), and the pinhole
// cannot be hit (t = 0). (s, t) = (1, 1) is not used at all: light reaching the camera
// unscattered is counted by s = 0 alone, which is why MISWeight gives s + t = 2 weight 1
// and its recurrence never counts (1, 1) as a competitor of (0, 2). The cases below check
// that the weights of the strategies that remain still sum to 1 in each of these cases.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "bdpt_internal.h"
#include "scene.h"

using namespace tessera;
using namespace tessera::bdpt_internal;

namespace {

uint32_t AddMaterial(SceneDesc& d, Color albedo, Color emission, std::optional<MaterialParams> preview = {}) {
    d.materials.push_back({albedo, emission, false, preview});
    return uint32_t(d.materials.size() - 1);
}

// Quad a-b-c-e, counter-clockwise seen from its front (where its normal points).
void AddQuad(SceneDesc& d, Vec3 a, Vec3 b, Vec3 c, Vec3 e, uint32_t material) {
    uint32_t base = uint32_t(d.positions.size() / 3);
    for (Vec3 p : {a, b, c, e}) d.positions.insert(d.positions.end(), {p.x, p.y, p.z});
    d.indices.insert(d.indices.end(), {base, base + 1, base + 2, base, base + 2, base + 3});
    d.triangle_material.insert(d.triangle_material.end(), {material, material});
}

// A room: Lambertian floor (y = 0) and back wall (z = -5), a smooth mirror on the left
// (x = -4, facing +x), rough metal on the right (x = 4, facing -x), a glass pane standing
// at z = 1 (x in [1, 3]), a small area light facing down at y = 4 and a point light.
SceneDesc Room() {
    SceneDesc d;
    const uint32_t floor = AddMaterial(d, Color(0.5f), Color(0.f));
    const uint32_t wall = AddMaterial(d, Color(0.6f, 0.5f, 0.4f), Color(0.f));
    MaterialParams mirror;
    mirror.diffuse_color = Color(0.9f);
    mirror.metallic = 1.f;
    mirror.roughness = 0.f;
    MaterialParams rough = mirror;
    rough.roughness = 0.5f;
    MaterialParams glass;
    glass.opacity = 0.f;
    glass.roughness = 0.f;
    const uint32_t m_mirror = AddMaterial(d, Color(0.9f), Color(0.f), mirror);
    const uint32_t m_rough = AddMaterial(d, Color(0.9f), Color(0.f), rough);
    const uint32_t m_glass = AddMaterial(d, Color(0.f), Color(0.f), glass);
    const uint32_t light = AddMaterial(d, Color(0.f), Color(10.f));
    AddQuad(d, {-5, 0, 5}, {5, 0, 5}, {5, 0, -5}, {-5, 0, -5}, floor);
    AddQuad(d, {-5, 0, -5}, {5, 0, -5}, {5, 5, -5}, {-5, 5, -5}, wall);
    AddQuad(d, {-4, 0.1f, 3}, {-4, 0.1f, -3}, {-4, 3, -3}, {-4, 3, 3}, m_mirror);
    AddQuad(d, {4, 0.1f, -3}, {4, 0.1f, 3}, {4, 3, 3}, {4, 3, -3}, m_rough);
    AddQuad(d, {1, 0.5f, 1}, {3, 0.5f, 1}, {3, 2.5f, 1}, {1, 2.5f, 1}, m_glass);
    AddQuad(d, {-0.5f, 4, -0.5f}, {0.5f, 4, -0.5f}, {0.5f, 4, 0.5f}, {-0.5f, 4, 0.5f}, light);
    d.point_lights.push_back({Vec3(1, 3, -1), Color(20.f)});
    return d;
}

Camera RoomCamera() {
    return Camera{Vec3(0, 1.5f, 4.5f), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, -1), 1.5f, 1.5f, 64, 64};
}

// A point of a full path: on a surface (found by tracing toward it), on the area light,
// at the point light, or the pinhole.
enum class Kind { kCamera, kSurface, kAreaLight, kPointLight };
struct PathPoint {
    Kind kind;
    Vec3 p;
};

class MISTest : public ::testing::Test {
protected:
    MISTest() : scene_(Room()), camera_(RoomCamera()), walker_(scene_, camera_, 64) {}

    // The hit of the ray from `from` toward `to` (which must be where it lands).
    SurfaceHit HitAt(Vec3 from, Vec3 to) const {
        SurfaceHit hit;
        const Vec3 d = Normalize(to - from);
        EXPECT_TRUE(scene_.Intersect({from, d}, &hit, 1e-4f)) << "nothing at the path point";
        EXPECT_LT(Length(hit.p - to), 1e-3f) << "the path point is occluded from its neighbour";
        return hit;
    }

    // A surface vertex at path[i] as a subpath coming from `prev` builds it.
    Vertex SurfaceVertex(const PathPoint& at, const PathPoint& prev, TransportMode mode) const {
        Vertex v;
        v.type = VertexType::kSurface;
        SurfaceHit hit = HitAt(prev.p, at.p);
        v.p = hit.p;
        v.ng = hit.ng;
        v.ns = hit.ns;
        v.importance = mode == TransportMode::Importance;
        v.wo = Normalize(prev.p - hit.p);
        v.hit = hit;
        v.emitter = scene_.EmitterAt(hit);
        v.bsdf = scene_.BSDFAt(hit, mode);
        v.frame = Frame::FromZ(hit.ns);
        v.delta = v.bsdf.Flags() != kBSDFUnset && !v.bsdf.IsNonSpecular();
        return v;
    }

    // The light subpath's origin at a light point (`next` is the vertex it lights).
    Vertex LightVertex(const PathPoint& at, const PathPoint& next) const {
        Vertex v;
        v.type = VertexType::kLight;
        if (at.kind == Kind::kPointLight) {
            v.emitter = int32_t(scene_.num_emitters() - 1);  // lights: area triangles, then the point
            EXPECT_TRUE(scene_.IsDeltaLight(uint32_t(v.emitter)));
            v.p = at.p;
            v.delta_light = true;
        } else {
            SurfaceHit hit = HitAt(next.p, at.p);
            v.emitter = scene_.EmitterAt(hit);
            EXPECT_GE(v.emitter, 0);
            v.p = hit.p;
            v.ng = v.ns = hit.ng;
            v.hit = hit;
        }
        return v;
    }

    Vertex CameraVertex() const {
        Vertex v;
        v.type = VertexType::kCamera;
        v.p = camera_.origin;
        v.beta = Color(1.f);
        return v;
    }

    // Forward densities as RandomWalk stores them: pdf_fwd of each vertex from its
    // predecessor (0 after a delta vertex), pdf_rev of each vertex from its successor.
    void FillDensities(std::vector<Vertex>& sub, bool camera_side) const {
        const size_t n = sub.size();
        for (size_t i = 1; i < n; ++i) {
            const Vertex& from = sub[i - 1];
            if (i == 1) {
                sub[1].pdf_fwd = camera_side
                                     ? ConvertDensity(camera_.PdfDirection(from.p, DirectionTo(from, sub[1])), from, sub[1])
                                     : walker_.PdfLight(from, sub[1]);
            } else {
                sub[i].pdf_fwd = from.delta ? 0.f : walker_.Pdf(from, &sub[i - 2], sub[i]);
            }
            if (i + 1 < n) sub[i - 1].pdf_rev = sub[i].delta ? 0.f : walker_.Pdf(sub[i], &sub[i + 1], sub[i - 1]);
        }
        if (!camera_side) sub[0].pdf_fwd = walker_.PdfLightOrigin(sub[0], sub[1]);
    }

    // Can strategy (s, t) generate the path? The rule the connection code follows.
    static bool Valid(const std::vector<Vertex>& light, const std::vector<Vertex>& camera, int s, int t) {
        if (t < 1 || (s == 1 && t == 1)) return false;
        if (s == 0) return camera[t - 1].type == VertexType::kSurface && camera[t - 1].IsLight();
        if (t == 1) return light[s - 1].type == VertexType::kSurface && light[s - 1].Connectible();
        if (s == 1) return camera[t - 1].Connectible();
        return light[s - 1].Connectible() && camera[t - 1].Connectible();
    }

    struct Split {
        std::vector<Vertex> light, camera;
    };

    // Subpaths of strategy (s, t) for path x_0 (camera) ... x_k (light).
    Split MakeSplit(const std::vector<PathPoint>& x, int s) const {
        const int k = int(x.size()) - 1, t = k + 1 - s;
        Split sp;
        sp.camera.push_back(CameraVertex());
        for (int i = 1; i < t; ++i) sp.camera.push_back(SurfaceVertex(x[i], x[i - 1], TransportMode::Radiance));
        FillDensities(sp.camera, true);
        if (s > 0) {
            sp.light.push_back(LightVertex(x[k], x[k - 1]));
            for (int j = 1; j < s; ++j)
                sp.light.push_back(SurfaceVertex(x[k - j], x[k - j + 1], TransportMode::Importance));
            if (s > 1) {
                FillDensities(sp.light, false);
            } else {
                sp.light[0].pdf_fwd = walker_.PdfLightOrigin(sp.light[0], sp.camera[t - 1]);
            }
        }
        return sp;
    }

    // The full-path density of strategy (s, t), up to the factors every valid strategy
    // shares: camera-side densities of x_1..x_{t-1} times light-side densities of
    // x_t..x_k, each from the full path directly (deltas count as 1, as they cancel).
    float PathDensity(const std::vector<PathPoint>& x, int s) const {
        const int k = int(x.size()) - 1, t = k + 1 - s;
        // x_0..x_k as one camera subpath (x_{k-1} last if x_k is a point, never hit).
        std::vector<Vertex> cam{CameraVertex()};
        const int last = x[k].kind == Kind::kPointLight ? k - 1 : k;
        for (int i = 1; i <= last; ++i) cam.push_back(SurfaceVertex(x[i], x[i - 1], TransportMode::Radiance));
        FillDensities(cam, true);
        // x_k .. x_1 as one light subpath (x_0, the pinhole, is never generated by it).
        std::vector<Vertex> lig;
        lig.push_back(LightVertex(x[k], x[k - 1]));
        for (int j = 1; j < k; ++j) lig.push_back(SurfaceVertex(x[k - j], x[k - j + 1], TransportMode::Importance));
        if (lig.size() > 1) FillDensities(lig, false);
        else lig[0].pdf_fwd = walker_.PdfLightOrigin(lig[0], cam[k - 1]);
        double p = 1.0;
        for (int i = 1; i < t; ++i) p *= Remap0(cam[i].pdf_fwd);
        for (int i = t; i <= k; ++i) p *= Remap0(lig[k - i].pdf_fwd);
        return float(p);
    }

    // Checks the partition of unity for path x; returns the valid strategies' s values.
    std::vector<int> CheckPath(const std::vector<PathPoint>& x, const char* what) {
        SCOPED_TRACE(what);
        const int k = int(x.size()) - 1;
        const bool delta_light_end = x.back().kind == Kind::kPointLight;
        std::vector<int> valid;
        std::vector<float> weights;
        for (int s = 0; s <= k; ++s) {
            const int t = k + 1 - s;
            if (s == 0 && delta_light_end) continue;  // a point light is never hit
            Split sp = MakeSplit(x, s);
            if (!Valid(sp.light, sp.camera, s, t)) {
                // The connection code refuses these before it samples anything.
                if (!(s == 1 && t == 1)) {
                    PixelSampler sampler(0, 0, 0);
                    Vertex sampled;
                    float px, py;
                    EXPECT_TRUE(IsBlack(walker_.Connect(sp.light.data(), sp.camera.data(), s, t, sampler, &sampled,
                                                        &px, &py)))
                        << "strategy (" << s << ", " << t << ") should not connect";
                }
                continue;
            }
            Vertex sampled = s == 1 ? sp.light[0] : (t == 1 ? sp.camera[0] : Vertex{});
            const float w = walker_.MISWeight(sp.light.data(), sp.camera.data(), sampled, s, t);
            EXPECT_TRUE(std::isfinite(w) && w >= 0.f && w <= 1.f + 1e-6f) << "(s, t) = (" << s << ", " << t << ")";
            valid.push_back(s);
            weights.push_back(w);
        }
        double sum = 0.0, sum_p2 = 0.0;
        for (float w : weights) sum += w;
        EXPECT_NEAR(sum, 1.0, 1e-5) << valid.size() << " valid strategies";
        // Each weight is the power heuristic of the full-path densities.
        std::vector<double> p2;
        for (int s : valid) {
            const double p = PathDensity(x, s);
            p2.push_back(p * p);
            sum_p2 += p * p;
        }
        for (size_t i = 0; i < valid.size(); ++i)
            EXPECT_NEAR(weights[i], p2[i] / sum_p2, 1e-4 * std::max(1.0, p2[i] / sum_p2))
                << "(s, t) = (" << valid[i] << ", " << k + 1 - valid[i] << ")";
        return valid;
    }

    Scene scene_;
    Camera camera_;
    Walker walker_;
};

const PathPoint kEye{Kind::kCamera, Vec3(0, 1.5f, 4.5f)};
const PathPoint kLight{Kind::kAreaLight, Vec3(0.1f, 4, 0.2f)};
const PathPoint kPoint{Kind::kPointLight, Vec3(1, 3, -1)};
const PathPoint kFloorA{Kind::kSurface, Vec3(-0.5f, 0, -1)};
const PathPoint kFloorB{Kind::kSurface, Vec3(0.7f, 0, -2.5f)};
const PathPoint kWall{Kind::kSurface, Vec3(-1, 2, -5)};
const PathPoint kMirror{Kind::kSurface, Vec3(-4, 1.5f, 0.5f)};
const PathPoint kRough{Kind::kSurface, Vec3(4, 1.2f, -0.5f)};
const PathPoint kGlassFront{Kind::kSurface, Vec3(2, 1.5f, 1)};

}  // namespace

TEST_F(MISTest, MaterialsAreWhatTheCasesNeed) {
    auto bsdf_at = [&](const PathPoint& from, const PathPoint& at) {
        return scene_.BSDFAt(HitAt(from.p, at.p), TransportMode::Radiance);
    };
    EXPECT_FALSE(bsdf_at(kEye, kMirror).IsNonSpecular());      // delta only
    EXPECT_FALSE(bsdf_at(kEye, kGlassFront).IsNonSpecular());  // delta only
    EXPECT_TRUE(bsdf_at(kFloorA, kRough).IsGlossy());
    EXPECT_TRUE(bsdf_at(kEye, kFloorA).IsNonSpecular());
}

TEST_F(MISTest, CameraSeesTheLightDirectly) {
    // Only (0, 2): (1, 1) is excluded and t = 0 impossible.
    EXPECT_EQ(CheckPath({kEye, kLight}, "E L"), (std::vector<int>{0}));
}

TEST_F(MISTest, DiffusePathsUseEveryStrategy) {
    EXPECT_EQ(CheckPath({kEye, kFloorA, kLight}, "E D L"), (std::vector<int>{0, 1, 2}));
    EXPECT_EQ(CheckPath({kEye, kWall, kFloorB, kLight}, "E D D L"), (std::vector<int>{0, 1, 2, 3}));
    EXPECT_EQ(CheckPath({kEye, kFloorA, kRough, kWall, kLight}, "E D G D L"), (std::vector<int>{0, 1, 2, 3, 4}));
}

TEST_F(MISTest, SpecularVerticesRemoveTheStrategiesThatWouldConnectThem) {
    // E S D L: the mirror vertex cannot be connected: (2, 2) and (3, 1) are out.
    EXPECT_EQ(CheckPath({kEye, kMirror, kFloorA, kLight}, "E S D L"), (std::vector<int>{0, 1}));
    // E D S L: a caustic seen on the floor: NEE at the mirror (1, 3) and the connection
    // floor-mirror (2, 2) are out; the camera path hitting the light (0, 4) and the light
    // tracer's (3, 1) remain.
    EXPECT_EQ(CheckPath({kEye, kFloorB, kMirror, kLight}, "E D S L"), (std::vector<int>{0, 3}));
    // Through glass: E S D L with a refraction at the pane.
    EXPECT_EQ(CheckPath({kEye, kGlassFront, kFloorB, kLight}, "E T D L"), (std::vector<int>{0, 1}));
}

TEST_F(MISTest, DeltaLightsAreNeverHit) {
    // E D P: (0, 3) cannot hit the point: NEE and the light tracer share the path.
    EXPECT_EQ(CheckPath({kEye, kFloorA, kPoint}, "E D P"), (std::vector<int>{1, 2}));
    EXPECT_EQ(CheckPath({kEye, kWall, kFloorB, kPoint}, "E D D P"), (std::vector<int>{1, 2, 3}));
    // E D S P: a point light's caustic: only the light tracer's (3, 1) can make it.
    EXPECT_EQ(CheckPath({kEye, kFloorB, kMirror, kPoint}, "E D S P"), (std::vector<int>{3}));
}

TEST_F(MISTest, RandomPathsSumToOne) {
    // Random full paths: 1 to 4 vertices on the floor, the back wall and the rough metal
    // (never twice in a row on one plane), ending on a random point of the area light or
    // at the point light; kept if every segment is unoccluded and the camera sees the first
    // vertex. Every one of them must pass CheckPath.
    std::mt19937 rng(20261122);
    std::uniform_real_distribution<float> u(0.f, 1.f);
    auto surface_point = [&](int surface) -> PathPoint {
        switch (surface) {
            case 0: return {Kind::kSurface, Vec3(-3.6f + 7.2f * u(rng), 0.f, -4.6f + 9.f * u(rng))};
            case 1: return {Kind::kSurface, Vec3(-4.6f + 9.2f * u(rng), 0.2f + 4.6f * u(rng), -5.f)};
            default: return {Kind::kSurface, Vec3(4.f, 0.3f + 2.5f * u(rng), -2.8f + 5.6f * u(rng))};
        }
    };
    auto visible = [&](Vec3 a, Vec3 b) {
        SurfaceHit hit;
        return scene_.Intersect({a, Normalize(b - a)}, &hit, 1e-4f) && Length(hit.p - b) < 1e-4f;
    };
    int checked = 0, strategies = 0;
    for (int attempt = 0; attempt < 20000 && checked < 60; ++attempt) {
        std::vector<PathPoint> x{kEye};
        const int n = 1 + int(u(rng) * 4.f);
        int last = -1;
        for (int i = 0; i < n; ++i) {
            int surface;
            do surface = int(u(rng) * 3.f) % 3; while (surface == last);
            last = surface;
            x.push_back(surface_point(surface));
        }
        x.push_back(u(rng) < 0.25f ? kPoint
                                   : PathPoint{Kind::kAreaLight, Vec3(-0.45f + 0.9f * u(rng), 4.f, -0.45f + 0.9f * u(rng))});
        float px, py, c;
        bool ok = camera_.Project(Normalize(x[1].p - kEye.p), &px, &py, &c);
        for (size_t i = 0; ok && i + 1 < x.size(); ++i) {
            // Toward an area light, from below only (it emits downward).
            ok = visible(x[i].p, x[i + 1].p) && (x[i + 1].kind != Kind::kAreaLight || x[i].p.y < 4.f);
        }
        if (!ok) continue;
        const std::string what = "random path " + std::to_string(checked) + " of " + std::to_string(x.size()) + " points";
        strategies += int(CheckPath(x, what.c_str()).size());
        ++checked;
    }
    EXPECT_EQ(checked, 60) << "too few random paths were unoccluded";
    EXPECT_GT(strategies, 2 * checked);  // most paths have several strategies to weigh
}
