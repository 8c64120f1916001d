// Form factors (Cohen & Wallace 1993, ch. 4). The point-to-polygon factor is exact:
// Lambert's contour integral over the polygon clipped to the receiver's hemisphere, so
// adjacent elements (a box's corner) get their factor without the 1/r^2 blow-up of disk
// approximations. An element's factor from a source averages it over 4 points of the
// receiver, each weighted by the visibility of one shadow ray through Embree to its
// counterpart on the source. Both solvers use this one estimator, so where the
// hierarchical solver's links reach the elements the two compute the same exchange.
#pragma once

#include <array>
#include <vector>

#include "scene.h"

namespace tessera {

// F from a differential area at x with unit normal n to the polygon `poly` (any winding),
// ignoring occlusion: (1/pi) of the polygon's projected solid angle above x's plane.
float PointToPolygonFormFactor(Vec3 x, Vec3 n, const Vec3* poly, size_t count);
float PointToPolygonFormFactor(Vec3 x, Vec3 n, const std::vector<Vec3>& poly);
float PointToTriangleFormFactor(Vec3 x, Vec3 n, const Vec3 tri[3]);

// The centroids of a triangle's m^2 similar sub-triangles (its regular subdivision, m per
// edge: equal areas), as the weights (b1, b2) of edges p1 - p0 and p2 - p0.
std::vector<std::array<float, 2>> SubTriangleCentroids(int m);

// Unoccluded area-to-area F_{A->B} = (1/|A|) Int_A F_{dA->B} dA for planar convex
// polygons, by the midpoint rule over a fan of triangles, each cut into `cells_per_edge`^2
// similar sub-triangles (the inner integrand is exact).
float PolygonToPolygonFormFactor(const std::vector<Vec3>& a, const std::vector<Vec3>& b, int cells_per_edge);

// Unoccluded factor of receiver triangle `rec` (its side facing nr) from triangle `src`:
// the mean of the point factor at the centroids of rec's 4 half-edge sub-triangles (equal
// areas: the midpoint rule for (1/|rec|) Int_rec F_{dA->src} dA). Fk gets the 4 point factors.
float ReceiverMeanFormFactor(const Vec3 rec[3], Vec3 nr, const Vec3 src[3], float Fk[4]);

// The same mean with visibility: point k's factor Fk[k] counts when the shadow ray from it
// to the point of src with the same barycentrics is clear (ends offset by eps along nr and
// ns, the side src emits from). `visible` (optional) gets the number of clear rays.
float VisibleReceiverMeanFormFactor(const Scene& scene, const Vec3 rec[3], Vec3 nr, const Vec3 src[3], Vec3 ns,
                                    float eps, const float Fk[4], int* visible);

}  // namespace tessera
