// Fresnel reflectance (fresnel.h): known values, total internal reflection, reciprocity.
#include <gtest/gtest.h>

#include <cmath>

#include "fresnel.h"
#include "math.h"

using namespace tessera;

TEST(Fresnel, DielectricKnownValues) {
    for (float ior : {1.33f, 1.5f, 2.4f}) {
        EXPECT_NEAR(FrDielectric(1.f, ior), F0FromIor(ior), 1e-6f);
        EXPECT_NEAR(FrDielectric(-1.f, ior), F0FromIor(ior), 1e-6f);  // same from inside
        EXPECT_NEAR(FrDielectric(0.f, ior), 1.f, 1e-6f);               // grazing
        // Total internal reflection beyond the critical angle, seen from inside.
        float cos_c = std::sqrt(1.f - 1.f / (ior * ior));
        EXPECT_EQ(FrDielectric(-(cos_c * 0.99f), ior), 1.f);
        EXPECT_LT(FrDielectric(-std::min(1.f, cos_c * 1.01f + 0.01f), ior), 1.f);
        // Reciprocity: the same R from either side of a refraction pair (Snell).
        for (float ci : {0.9f, 0.5f, 0.1f}) {
            float sin_t = std::sqrt(1.f - ci * ci) / ior, ct = std::sqrt(1.f - sin_t * sin_t);
            EXPECT_NEAR(FrDielectric(ci, ior), FrDielectric(-ct, ior), 1e-5f);
        }
    }
    EXPECT_NEAR(F0FromIor(1.5f), 0.04f, 1e-6f);
    EXPECT_EQ(FrDielectric(0.f, 1.f), 0.f);  // an index-matched interface, even at grazing
    EXPECT_EQ(FrDielectric(0.5f, 1.f), 0.f);
}

TEST(Fresnel, SchlickEndpoints) {
    Color f0(0.1f, 0.2f, 0.3f), f90(0.9f, 0.8f, 1.f);
    Color a = FrSchlick(f0, f90, 1.f), b = FrSchlick(f0, f90, 0.f);
    EXPECT_NEAR(a.x, 0.1f, 1e-6f);
    EXPECT_NEAR(a.z, 0.3f, 1e-6f);
    EXPECT_NEAR(b.y, 0.8f, 1e-6f);
    EXPECT_NEAR(FrSchlick(0.f, 1.f, 0.5f), 1.f / 32.f, 1e-7f);
    EXPECT_EQ(FrSchlick(0.04f, 1.f, -0.3f), 1.f);  // clamped, for callers passing raw cosines
}
